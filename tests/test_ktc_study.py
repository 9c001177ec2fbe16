"""The KTC study: a synthetic series made by the model recovered (its unknowns, its tanks predicted), electrodes out of
use, bad folders refused in one line; the training set itself in the slow run."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from electrosense.validation.bench.transfer.ktc_mat import KtcTruth, ktc_patterns, read_ktc_folder
from electrosense.validation.comparison.ktc import fit_ktc, predict_folder
from electrosense.validation.comparison.ktc_model import KtcForward, KtcGeometry, truth_objects, volts

KTC = Path(__file__).resolve().parents[2] / "shared" / "data" / "ktc2023" / "training"


def _mask(n=64):
    m = np.zeros((n, n), np.uint8)
    m[14:30, 36:50] = 2            # a metal block, upper right
    m[38:52, 12:22] = 1            # a plastic block, lower left
    return m


def _write_series(folder, E=8, dead=(), seed=0, water=0.0):
    """A series made by the model itself: known unknowns, noise of 0.02 % of the change's RMS per voltage; the
    tank file measured with every voltage scaled by ``1 + water`` (the water's change since the reference)."""
    rng = np.random.default_rng(seed)
    inj, mp = ktc_patterns(E)
    truth = KtcTruth(_mask(), 0.23)
    geom = KtcGeometry(width_deg=12.0, depth_m=0.05, height_frac=0.6, position=0.2, n_electrodes=E,
                       ring_rotation_deg=2.0)
    fw = KtcForward({"data1": truth_objects(truth)}, n_modes=6, segments_per_electrode=4, segments_per_gap=3)
    zeta = np.full(E, 1e-3)
    s = 0.03
    off = 1e-3 * rng.standard_normal(E - 1)
    U0 = s * volts(fw.impedance("ref", geom, zeta), inj, mp) + off
    U1 = (1 + water) * s * volts(fw.impedance("data1", geom, zeta), inj, mp) + off
    noise = 2e-4 * np.sqrt(np.mean((U1 - U0) ** 2))
    U0 = U0 + noise * rng.standard_normal(U0.shape)
    U1 = U1 + noise * rng.standard_normal(U1.shape)
    for U in (U0, U1):
        for e in dead:
            U[:, np.abs(mp[e - 1]) > 0] = np.nan
            U[np.abs(inj[e - 1]) > 0] = np.nan
    folder.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(folder / "ref.mat", {"Injref": inj, "Mpat": mp, "Uelref": U0.reshape(-1, 1)})
    scipy.io.savemat(folder / "data1.mat", {"Inj": inj, "Mpat": mp, "Uel": U1.reshape(-1, 1)})
    scipy.io.savemat(folder / "true1.mat", {"truth": _mask()})
    return geom


def test_a_series_made_by_the_model_is_recovered_and_predicted(tmp_path):
    geom = _write_series(tmp_path / "fit", E=8)
    _write_series(tmp_path / "other", E=8, dead=(3,), seed=1)
    (tmp_path / "other" / "data2.mat").write_bytes((tmp_path / "other" / "data1.mat").read_bytes())   # no truth
    fit = fit_ktc(read_ktc_folder(tmp_path / "fit"), n_modes=6, progress=lambda s: None, max_nfev=8)
    assert fit.scores["ref_rms_rel"] < 0.01
    assert fit.values["ring_rotation_deg"] == pytest.approx(geom.ring_rotation_deg, abs=0.5)
    other = read_ktc_folder(tmp_path / "other")
    assert any("true2.mat" in n for n in other.notes)
    pred = predict_folder(fit, other, "other", progress=lambda s: None)
    m = pred["data1"]["metrics"]
    assert m["electrodes_out_of_use"] == [3] and m["patterns_left_out"]
    assert m["difference_rms_rel"] < 0.1 and np.isfinite(m["total_rms_rel"])
    assert abs(m["water_change_rel"]) < 3 * m["water_change_rel_se"] + 1e-3


def test_the_waters_change_since_the_reference_is_found_and_scored_held_out(tmp_path):
    _write_series(tmp_path / "fit", E=8)
    _write_series(tmp_path / "other", E=8, seed=1, water=-0.03)
    fit = fit_ktc(read_ktc_folder(tmp_path / "fit"), n_modes=6, progress=lambda s: None, max_nfev=8)
    m = predict_folder(fit, read_ktc_folder(tmp_path / "other"), "other", progress=lambda s: None)["data1"]["metrics"]
    assert m["water_change_rel"] == pytest.approx(-0.03, abs=2e-3)
    assert m["water_change_rel_se"] < 2e-3
    assert m["difference_rms_rel_reference_water"] > 5 * m["difference_rms_rel"]     # the scale swamps the change
    assert m["difference_rms_rel"] < 0.1


def test_bad_folders_are_refused_in_one_line(tmp_path):
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(main, ["study", "ktc", "--fit", str(tmp_path / "empty"), "-o", str(tmp_path / "o")])
    assert r.exit_code != 0 and "no ref.mat" in r.output and "Traceback" not in r.output
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "ref.mat").write_text("not a mat file")
    r = CliRunner().invoke(main, ["study", "ktc", "--fit", str(bad), "-o", str(tmp_path / "o")])
    assert r.exit_code != 0 and "ref.mat" in r.output and "Traceback" not in r.output


@pytest.mark.slow
@pytest.mark.skipif(not KTC.is_dir(), reason="the KTC2023 training set is not on this machine")
def test_the_training_set_with_electrodes_out_of_use(tmp_path):
    from electrosense.validation.studies.ktc import main

    var = tmp_path / "variant"
    var.mkdir()
    for f in ("ref.mat", "data2.mat"):
        d = scipy.io.loadmat(KTC / f)
        key = "Uelref" if f == "ref.mat" else "Uel"
        U = d[key].reshape(76, 31).copy()
        U[:, [4, 5, 20, 21]] = np.nan                 # electrodes 6 and 22 out of use
        U[np.abs(d["Injref" if f == "ref.mat" else "Inj"][[5, 21]]).max(axis=0) > 0] = np.nan
        scipy.io.savemat(var / f, {key: U.reshape(-1, 1), "Mpat": d["Mpat"],
                                   ("Injref" if f == "ref.mat" else "Inj"): d["Injref" if f == "ref.mat" else "Inj"]})
    shutil.copy(KTC / "true2.mat", var / "true2.mat")
    main(["--fit", str(KTC), "--predict", str(var), "-o", str(tmp_path / "out"), "--modes", "12"])
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["ref_rms_over_floor"] < 1.5
    p = m["predicted"]["variant/data2"]
    assert p["electrodes_out_of_use"] == [6, 22] and p["difference_rms_rel"] < 0.35


def test_regions_one_pixel_apart_stay_apart():
    from electrosense.meshes.prism_scene import _overlapping_objects

    m = np.zeros((64, 64), np.uint8)
    m[20:40, 10:30] = 1
    m[20:40, 31:50] = 2
    objs = truth_objects(KtcTruth(m, 0.23))
    assert [o.is_conducting for o in objs] == [False, True] and not _overlapping_objects(objs)


def test_the_empty_tanks_gap_is_diagnosed_by_the_engine(tmp_path):
    """A scene fitted in eight evaluations leaves a gap of its own (the electrodes' height not converged): the
    diagnosis engine (every fifth pattern held out, a detection test at 1 %) names one candidate that brings the
    held-out gap to its noise, with an interval for each parameter, and no less than the linear table's best."""
    from electrosense.validation.diagnosis.ktc_gap import diagnose_ktc

    _write_series(tmp_path / "fit", E=8)
    folder = read_ktc_folder(tmp_path / "fit")
    fit = fit_ktc(folder, n_modes=6, progress=lambda s: None, max_nfev=8)
    d = diagnose_ktc(fit, folder, {}, progress=lambda s: None)["metrics"]
    e = d["empty_tank_engine"]
    assert e["verdict"] == "explained" and d["empty_tank_chosen"] == e["chosen"] != "none", e["steps"]
    assert e["gap_before"] > 2 * e["noise_rel"] and e["gap_after"] < 1.5 * e["noise_rel"]
    table = d["empty_tank_candidates"]
    assert e["gap_after"] < 1.5 * min(v["heldout_rms_rel"] for v in table.values())
    for name, ps in e["parameters"].items():
        for p, v in ps.items():
            lo, hi = e["interval_95"][name][p]
            assert lo < v < hi
