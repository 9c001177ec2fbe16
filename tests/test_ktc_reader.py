"""The KTC2023 layout: read as the files ship, refused with file, array and reason otherwise, and the data's
own linear floor (what no medium can explain), on synthetic files and, where shared/ has them, the real ones."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.transfer.ktc_mat import ktc_patterns, linear_floor, read_ktc_mat, read_ktc_truth

KTC = Path(__file__).resolve().parents[2] / "shared" / "data" / "ktc2023" / "training"


def _tank(rng, E=16, noise=0.0, dead=()):
    """Patterns as KTC drives them (adjacent on the odd electrodes, then all against one), a random linear
    medium (a symmetric resistance matrix on the electrodes), adjacent measurements; NaN on dead electrodes."""
    inj, mpat = ktc_patterns(E)
    G = rng.uniform(0.5, 1.5, (E, E))
    R = np.linalg.pinv(np.diag((G + G.T).sum(1)) - (G + G.T))       # electrode potentials per current
    U = inj.T @ R @ mpat
    U = U * (1 + noise * rng.standard_normal(U.shape))
    for e in dead:
        U[:, np.flatnonzero(mpat[e - 1])] = np.nan
    return inj, mpat, U


def _save(path, inj, mpat, U, ref=False):
    names = ("Injref", "Mpat", "Uelref") if ref else ("Inj", "Mpat", "Uel")
    scipy.io.savemat(path, dict(zip(names, (inj, mpat.astype(np.int16), U.reshape(-1, 1)))))
    return path


@pytest.mark.parametrize("ref", [True, False])
def test_read_and_the_floor_of_a_linear_medium(tmp_path, ref):
    rng = np.random.default_rng(1)
    inj, mpat, U = _tank(rng)
    m = read_ktc_mat(_save(tmp_path / "x.mat", inj, mpat, U, ref))
    np.testing.assert_array_equal(m.voltages_V, U)
    f = linear_floor(m.injection, m.voltages_V)
    assert f["floor_rms_rel"] < 1e-12 and f["rank"] == np.linalg.matrix_rank(inj)
    assert f["relations"] == U.size - f["rank"] * U.shape[1]


def test_the_floor_measures_independent_noise_and_skips_dead_electrodes(tmp_path):
    rng = np.random.default_rng(2)
    inj, mpat, U = _tank(rng, E=32, noise=0.01, dead=(7,))
    m = read_ktc_mat(_save(tmp_path / "d.mat", inj, mpat, U))
    assert m.electrodes_out_of_use == [7]     # 6 and 8 are read by their other neighbours
    f = linear_floor(m.injection, m.voltages_V)
    assert 0.008 < f["noise_rms_rel"] < 0.012                     # 1 % of each voltage, independent
    assert np.isnan(f["residual"][:, np.flatnonzero(mpat[6])]).all()


@pytest.mark.parametrize("case,message", [
    ("no Uel", "no array Uel or Uelref"), ("wrong size", r"Uel holds \d+ values, not \d+ patterns x 15"),
    ("unbalanced", "pattern 3's currents sum to"), ("inf", "infinite"), ("text", "not a readable .mat file")])
def test_what_cannot_be_read_is_refused(tmp_path, case, message):
    inj, mpat, U = _tank(np.random.default_rng(3))
    p = tmp_path / "bad.mat"
    if case == "no Uel":
        scipy.io.savemat(p, {"Inj": inj, "Mpat": mpat})
    elif case == "wrong size":
        scipy.io.savemat(p, {"Inj": inj, "Mpat": mpat, "Uel": U.reshape(-1, 1)[:-3]})
    elif case == "unbalanced":
        inj = inj.copy()
        inj[0, 2] += 0.1
        _save(p, inj, mpat, U)
    elif case == "inf":
        U = U.copy()
        U[0, 0] = np.inf
        _save(p, inj, mpat, U)
    else:
        p.write_text("Uel = 1\n")
    with pytest.raises(BenchLogError, match=message) as info:
        read_ktc_mat(p)
    assert str(info.value).startswith(str(p))


def test_truth_mask_and_its_frame(tmp_path):
    mask = np.zeros((8, 8), np.uint8)
    mask[0, 7] = 2                                                    # top right: +x, +y
    scipy.io.savemat(tmp_path / "t.mat", {"truth": mask})
    t = read_ktc_truth(tmp_path / "t.mat")
    x, y = t.centres_m()
    assert x[7] > 0 and y[0] > 0 and abs(t.pixel_m - 0.23 / 8) < 1e-15
    scipy.io.savemat(tmp_path / "u.mat", {"truth": mask + 3})
    with pytest.raises(BenchLogError, match="values other than 0"):
        read_ktc_truth(tmp_path / "u.mat")


@pytest.mark.skipif(not (KTC / "ref.mat").exists(), reason="the KTC2023 training set is not beside the checkout")
def test_the_real_empty_tank_floor():
    """76 patterns spanning 15 dimensions; the voltages miss the linear relations by 4.3 % RMS of themselves
    (4.8 % per voltage, counted by the relations' degrees of freedom: 21 mV)."""
    m = read_ktc_mat(KTC / "ref.mat")
    f = linear_floor(m.injection, m.voltages_V)
    assert m.voltages_V.shape == (76, 31) and f["rank"] == 15 and f["relations"] == 61 * 31
    assert 0.040 < f["floor_rms_rel"] < 0.046 and 0.045 < f["noise_rms_rel"] < 0.051
    assert read_ktc_truth(KTC / "true1.mat").mask.shape == (256, 256)
