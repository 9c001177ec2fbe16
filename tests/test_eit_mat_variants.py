"""Every file of the EIT phantom layout a user may hold is read, or refused with the file, the array and the reason.

The files are made here (random electrode counts and values, the adjacent protocol's zeros), then mutated as
other files of the layout differ: the arrays' spelling and letter case, an array missing, several frames, the
opposite polarity; and broken: non-finite values, a dead channel, a truncated file, another layout. The
command line on each broken file prints one line, never a traceback.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner

from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.transfer.eit_mat import read_eit_mat
from electrosense.validation.cli import main


def _layout(rng, n: int, setups=("Ref", "Avg1")) -> dict:
    """Arrays of one file: per set-up vv (n*n, drive-major, zeros where a measurement touches a drive electrode),
    the source current (constant) under the name volts, the drive voltage (varying) under curr, as in the sample."""
    d = {"description": np.array(["made by the test"])}
    for s in setups:
        vv = rng.uniform(0.05, 1.0, (n, n))
        for k in range(n):
            vv[k, [(k - 1) % n, k, (k + 1) % n]] = 0.0
        d["vv" + s] = vv.reshape(-1, 1)
        d["volts" + s] = np.full((n, 1), 4.6e-3) * (1 + 1e-5 * rng.standard_normal((n, 1)))
        d["curr" + s] = rng.uniform(2.9, 3.9, (n, 1))
    return d


def _save(tmp_path, name, d):
    p = tmp_path / name
    scipy.io.savemat(p, d)
    return p


@pytest.fixture(params=[8, 16, 32])
def layout(request):
    rng = np.random.default_rng(request.param)
    return request.param, _layout(rng, request.param)


def _rows(path):
    rows, meta = read_eit_mat(path)
    return {(r[0], *r[1:5]): r[5:] for r in rows}, meta


def test_the_sample_layout_any_electrode_count(tmp_path, layout):
    n, d = layout
    rows, meta = _rows(_save(tmp_path, "a.mat", d))
    assert len(rows) == 2 * (n + n * (n - 3))
    assert meta["current_field"] == {"Ref": "voltsRef", "Avg1": "voltsAvg1"}
    vv = d["vvRef"].reshape(n, n)
    assert rows[("Ref", 1, 2, 5, 4)] == (vv[0, 3], d["voltsRef"][0, 0])


@pytest.mark.parametrize("rename", [
    {"voltsRef": "voltRef"},                                              # the second Ottawa file
    {"voltsRef": "VOLTSRef", "currAvg1": "CurrentAvg1", "vvAvg1": "VVAvg1"},
    {"currRef": "curRef", "voltsAvg1": "VoltageAvg1"},
])
def test_field_name_variants_read_the_same_numbers(tmp_path, layout, rename):
    n, d = layout
    ref, _ = _rows(_save(tmp_path, "a.mat", d))
    renamed = {rename.get(k, k): v for k, v in d.items()}
    got, meta = _rows(_save(tmp_path, "b.mat", renamed))
    assert got == ref
    assert meta["current_field"]["Ref"] == rename.get("voltsRef", "voltsRef")


def test_a_missing_drive_voltage_or_current(tmp_path, layout):
    n, d = layout
    ref, _ = _rows(_save(tmp_path, "a.mat", d))
    no_voltage, meta = _rows(_save(tmp_path, "b.mat", {k: v for k, v in d.items() if not k.startswith("curr")}))
    assert no_voltage == {k: v for k, v in ref.items() if k[1:3] != k[3:5]}      # the drive pairs' rows go
    assert meta["voltage_field"]["Ref"] is None and "current_unit" not in meta
    no_current, meta = _rows(_save(tmp_path, "c.mat", {k: v for k, v in d.items() if not k.startswith("volts")}))
    assert "unknown" in meta["current_unit"] and meta["current_field"]["Ref"] is None
    assert all(v[1] == 1.0 for v in no_current.values()) and no_current.keys() == ref.keys()
    only_vv, meta = _rows(_save(tmp_path, "d.mat", {k: v for k, v in d.items() if k.startswith("vv")}))
    assert only_vv.keys() == no_voltage.keys()


def test_frames_are_averaged_and_said(tmp_path, layout):
    n, d = layout
    rng = np.random.default_rng(0)
    frames = {k: (v * (1 + 1e-3 * rng.standard_normal((v.shape[0], 5))) if k.startswith("vv") else v)
              for k, v in d.items()}
    got, meta = _rows(_save(tmp_path, "f.mat", frames))
    np.testing.assert_allclose(got[("Ref", 1, 2, 5, 4)][0], frames["vvRef"].reshape(n, n, 5)[0, 3].mean())
    assert any("mean of 5 frames" in note for note in meta["reader_notes"])


def test_the_opposite_polarity_is_turned_round_and_said(tmp_path, layout):
    n, d = layout
    ref, _ = _rows(_save(tmp_path, "a.mat", d))
    got, meta = _rows(_save(tmp_path, "n.mat", {k: (-v if k.startswith("vv") else v) for k, v in d.items()}))
    assert got == ref and any("opposite polarity" in note for note in meta["reader_notes"])


def test_measured_values_on_the_drive_electrodes_are_left_out_and_counted(tmp_path, layout):
    n, d = layout
    ref, _ = _rows(_save(tmp_path, "a.mat", d))
    vv = d["vvRef"].reshape(n, n).copy()
    vv[vv == 0] = 0.7
    got, meta = _rows(_save(tmp_path, "t.mat", {**d, "vvRef": vv.reshape(-1, 1)}))
    assert got == ref and any(f"{3 * n} values on measurements touching" in note for note in meta["reader_notes"])


def _broken(d, n):
    vv_nan = d["vvAvg1"].copy()
    vv_nan[n + 4] = np.nan
    vv_zero = d["vvRef"].copy()
    vv_zero[4] = 0.0
    vv_mixed = d["vvRef"].copy()
    vv_mixed[4] *= -1
    return {
        "non-finite": ({**d, "vvAvg1": vv_nan}, "vvAvg1 holds non-finite values"),
        "dead channel": ({**d, "vvRef": vv_zero}, r"vvRef: drive 1, measurement 5 is 0"),
        "mixed signs": ({**d, "vvRef": vv_mixed}, r"vvRef: drive 1, measurement 5 is -"),
        "not n*n": ({**d, "vvRef": d["vvRef"][:-3]}, r"vvRef has shape \(\d+, 1\): not n\*n"),
        "negative current": ({**d, "voltsRef": -d["voltsRef"]}, "voltsRef: drive 1 holds -"),
        "wrong length": ({**d, "currAvg1": d["currAvg1"][:-1]}, f"currAvg1: {n - 1} values, expected {n}"),
        "two spellings": ({**d, "voltRef": d["voltsRef"]}, "voltsRef, voltRef all name the same quantity"),
        "text array": ({**d, "vvRef": np.array(["abc"])}, "vvRef: expected a numeric array"),
        "other layout": ({"x": np.ones(3)}, r"no vv<setup> array: not the EIT phantom layout \(arrays: x\)"),
    }


@pytest.mark.parametrize("case", ["non-finite", "dead channel", "mixed signs", "not n*n", "negative current",
                                  "wrong length", "two spellings", "text array", "other layout"])
def test_what_cannot_be_read_is_refused_with_file_array_and_reason(tmp_path, case):
    n = 8
    d, message = _broken(_layout(np.random.default_rng(3), n), n)[case]
    p = _save(tmp_path, "bad.mat", d)
    with pytest.raises(BenchLogError, match=message) as info:
        read_eit_mat(p)
    assert str(info.value).startswith(str(p))


@pytest.mark.parametrize("damage", ["truncated", "empty", "text", "missing"])
def test_the_command_line_says_one_line_and_no_traceback(tmp_path, damage):
    good = _save(tmp_path, "good.mat", _layout(np.random.default_rng(4), 8))
    bad = tmp_path / "bad.mat"
    if damage == "truncated":
        bad.write_bytes(good.read_bytes()[:300])
    elif damage == "empty":
        bad.write_bytes(b"")
    elif damage == "text":
        bad.write_text("vvRef = [1 2 3]\n")
    scene = tmp_path / "tank.toml"
    scene.write_text('[tank]\nshape = "cylinder"\nradius_m = 0.1\nheight_m = 0.2\n'
                     '[electrode_ring]\nn = 8\nz_m = 0.0\nradius_m = 0.005\n'
                     '[protocol]\nring = [1, 2, 3, 4, 5, 6, 7, 8]\nreference = "Ref"\n')
    res = CliRunner().invoke(main, ["study", "real_tank", "--data", str(bad), "--scene", str(scene),
                                    "-o", str(tmp_path / "out")])
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert isinstance(res.exception, SystemExit)           # the command's one line, not an escaped exception
    assert "bad.mat" in str(res.exception) and str(res.exception).startswith("esense: error: ")


def test_the_files_electrodes_become_the_scenes_ring(tmp_path):
    """Electrode k of the file is the k-th of the scene's [protocol] ring; a ring of another length is refused."""
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.bench.transfer.log import read_transfer_log

    n = 8
    p = _save(tmp_path, "a.mat", _layout(np.random.default_rng(5), n, setups=("Ref",)))
    ring = list(range(20, 20 + 2 * n, 2))                        # the scene's electrodes 20, 22, ..., 34
    plain = read_transfer_log(eit_mat_to_transfer_log(p, tmp_path / "plain.csv", scene="s.toml"))
    mapped = read_transfer_log(eit_mat_to_transfer_log(p, tmp_path / "mapped.csv", scene="s.toml", ring=ring))
    np.testing.assert_array_equal(mapped.V_V, plain.V_V)
    np.testing.assert_array_equal(mapped.drive, np.asarray(ring)[plain.drive - 1])
    np.testing.assert_array_equal(mapped.measure, np.asarray(ring)[plain.measure - 1])
    with pytest.raises(BenchLogError, match="the file's ring has 8 electrodes, the scene's \\[protocol\\] ring 16"):
        eit_mat_to_transfer_log(p, tmp_path / "x.csv", scene="s.toml", ring=range(1, 17))


def test_the_blind_phantoms_instrument_adds_its_fault_where_it_belongs():
    """``esense study phantom_blind``'s instrument on a ring of resistors: the crosstalk lands on its parity class
    (the mixed classes alike, so reciprocity holds), the quadrature common mode leaves a row whose pair sits
    where the common-mode voltage vanishes, the rows touching a drive are zero, and the gains multiply."""
    from electrosense.bem.protocol import adjacent_protocol, involves_drive, transfer_impedances_ohm
    from electrosense.validation.studies.phantom_blind import CROSSTALK_OF_MEDIAN, CURRENT_A, instrument_reading

    n = 8
    K = np.zeros((n, n))
    for i in range(n):            # 1 S between neighbours, 0.2 S across
        for j, g in (((i + 1) % n, 1.0), ((i + n // 2) % n, 0.2)):
            K[i, j] = K[j, i] = -g
    K[np.diag_indices(n)] = -K.sum(axis=1)
    ring = list(range(1, n + 1))
    d, m = adjacent_protocol(ring)
    touched = involves_drive(d, m)
    Z = np.abs(transfer_impedances_ohm(K, d, m))
    rng = np.random.default_rng(0)
    zero = np.zeros(n), np.zeros((n, n))
    plain = instrument_reading(K, ring, "none", *zero, rng) / CURRENT_A
    assert np.all(plain[touched] == 0)
    assert np.allclose(plain[~touched], Z[~touched], rtol=5e-3)           # the frame noise only (0.05 %)
    crosstalk = instrument_reading(K, ring, "crosstalk", *zero, rng) / CURRENT_A - plain
    k, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    cls = 2 * (k % 2) + j % 2
    median = np.median(Z[~touched])
    for c, share in enumerate(CROSSTALK_OF_MEDIAN):
        assert np.allclose(crosstalk[~touched & (cls == c)], share * median, atol=0.01 * median)
    common = instrument_reading(K, ring, "common_mode", *zero, rng) / CURRENT_A
    far = (j - k) % n == n // 2          # measurement pair opposite the drive pair: V_cm = 0 by symmetry
    assert np.allclose(common[far & ~touched], Z[far & ~touched], rtol=5e-3)
    assert np.all(common[~far & ~touched] >= Z[~far & ~touched] * (1 - 5e-3))
    assert np.max(common[~touched] / Z[~touched]) > 1.01            # 2 % on this ring of resistors
    gains = 0.01 * np.arange(n)
    ratio = instrument_reading(K, ring, "none", gains, zero[1], rng) / CURRENT_A / np.where(touched, 1.0, plain)
    assert np.allclose(ratio[~touched], (1 + gains[None, :] + 0 * ratio)[~touched], rtol=4e-3)
