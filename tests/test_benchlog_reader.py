"""Bench-log reader and writer: round trips, every refusal of the spec with its message, cut-short lines."""
import numpy as np
import pandas as pd
import pytest

from electrosense.validation.bench.log import (
    BenchLogError,
    BenchLogWriter,
    read_bench_log,
    read_bench_logs,
    write_bench_log,
)

META = '# meta: {"sensor": "angels-4", "emitter": 4, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": 0.0354}'
COLUMNS = "t_s,x_m,y_m,z_m,yaw_rad,U_V,I1_A,I2_A,I3_A,temp_C"
ROW0 = "0.000,-0.3800,0.0000,0.0000,0.000000,1.000000,1.0314e-03,6.5521e-04,5.1230e-04,20.01"
ROW1 = "0.100,-0.3750,0.0000,0.0000,0.000000,1.000000,1.0310e-03,6.5500e-04,5.1200e-04,20.01"
META_DICT = {"sensor": "angels-4", "emitter": 4, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": 0.0354}


def _write(tmp_path, lines, end="\n", name="run.csv"):
    p = tmp_path / name
    p.write_bytes((("\n".join(lines)) + end).encode("utf-8") if isinstance(lines[0], str) else b"")
    return p


def _good(extra_rows=()):
    return ["# esense-bench-log 1", META, "# a comment", COLUMNS, ROW0, ROW1, *extra_rows]


def test_spec_example_reads_to_arrays(tmp_path):
    log = read_bench_log(_write(tmp_path, _good()))
    assert log.poses.shape == (2, 4) and log.currents_A.shape == (2, 3)
    np.testing.assert_array_equal(log.poses[0], [-0.38, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(log.currents_A[0], [1.0314e-03, 6.5521e-04, 5.1230e-04])
    np.testing.assert_array_equal(log.U_V, [1.0, 1.0])
    np.testing.assert_array_equal(log.t_s, [0.0, 0.1])
    np.testing.assert_array_equal(log.passes, [0, 0])
    assert log.sensor.name == "angels-4" and log.emitter == 4 and log.sensor.emitter == 4
    assert log.tank.size_m == (1.0, 1.0, 1.0) and log.tank.water_depth_m == 1.0
    assert log.sigma_S_per_m == 0.0354 and log.warnings == []
    assert list(log.data.columns) == COLUMNS.split(",")
    np.testing.assert_allclose(log.resistance_ohm[0], 1.0 / log.currents_A[0])


def test_extra_columns_kept_and_unknown_meta_kept(tmp_path):
    meta = META[:-1] + ', "operator": "ann"}'
    lines = ["# esense-bench-log 1", meta, COLUMNS + ",note,gain", ROW0 + ",start,1.5", ROW1 + ",end,2"]
    log = read_bench_log(_write(tmp_path, lines))
    assert log.meta["operator"] == "ann"
    assert log.data["note"].tolist() == ["start", "end"]
    assert log.data["gain"].tolist() == [1.5, 2.0]


def test_unbounded_water_and_sensor_file_relative_to_log(tmp_path):
    from electrosense.meshes.sensor import preset, save_sensor

    (tmp_path / "sensors").mkdir()
    save_sensor(preset("angels-2"), tmp_path / "sensors" / "my.json")
    meta = '# meta: {"sensor": "sensors/my.json", "emitter": 2, "tank_m": null, "sigma_S_per_m": 0.05}'
    lines = ["# esense-bench-log 1", meta, "t_s,x_m,y_m,z_m,yaw_rad,U_V,I1_A", "0,0,0,0,0,1,1e-3"]
    log = read_bench_log(_write(tmp_path, lines))
    assert log.tank is None and log.sensor.n_electrodes == 2 and log.currents_A.shape == (1, 1)


def test_cut_short_last_line_is_reported_and_skipped(tmp_path):
    lines = _good([ROW1.replace("0.100", "0.200")[:25]])
    log = read_bench_log(_write(tmp_path, lines, end=""))
    assert len(log) == 2
    assert len(log.warnings) == 1 and log.warnings[0].startswith("line 7: last line cut short, skipped")


def test_last_line_without_line_end_is_never_taken_even_if_it_parses(tmp_path):
    log = read_bench_log(_write(tmp_path, _good(), end=""))
    assert len(log) == 1 and "line 6" in log.warnings[0]


@pytest.mark.parametrize("mutate, line, reason", [
    (lambda L: ["# esense-bench-log 2"] + L[1:], 1, "unsupported bench-log version '2'"),
    (lambda L: ["t_s,x_m"] + L[1:], 1, "not a bench log: line 1 must be exactly"),
    (lambda L: L[:1] + ['# meta: {"sensor": "angels-4",'] + L[2:], 2, "bad JSON in the meta line"),
    (lambda L: L[:1] + ["# meta: [1, 2]"] + L[2:], 2, "must hold a JSON object"),
    (lambda L: L[:1] + ["# metadata: {}"] + L[2:], 2, "line 2 must start with '# meta: '"),
    (lambda L: L[:1] + ['# meta: {"sensor": "angels-4", "emitter": 4, "tank_m": [1, 1, 1], "sigma_S_per_m": NaN}'] + L[2:],
     2, "NaN is not valid JSON"),
    (lambda L: L[:1] + ['# meta: {"sensor": "angels-4", "emitter": 4, "tank_m": [1, 1, 1]}'] + L[2:], 2,
     "lacks the required key 'sigma_S_per_m'"),
    (lambda L: L[:1] + ['# meta: {"emitter": 4, "sigma_S_per_m": 0.03}'] + L[2:], 2,
     "lacks the required keys 'sensor', 'tank_m'"),
    (lambda L: L[:1] + [META.replace('"angels-4"', '"angels-9"')] + L[2:], 2, "neither a preset"),
    (lambda L: L[:1] + [META.replace('"emitter": 4', '"emitter": 5')] + L[2:], 2, "emitter' 5 is not an electrode"),
    (lambda L: L[:1] + [META.replace('"emitter": 4', '"emitter": "4"')] + L[2:], 2, "'emitter' must be an integer"),
    (lambda L: L[:1] + [META.replace("[1.0, 1.0, 1.0]", "[1.0, 1.0]")] + L[2:], 2, "'tank_m' must be [Lx, Ly, Lz]"),
    (lambda L: L[:1] + [META.replace("0.0354", "-1")] + L[2:], 2, "'sigma_S_per_m' must be a positive number"),
    (lambda L: L[:1] + [META[:-1] + ', "water_depth_m": 2.0}'] + L[2:], 2, "water depth 2.0 m must lie in"),
    (lambda L: L[:3] + [COLUMNS.replace("yaw_rad,", "")] + L[4:], 4, "missing required column yaw_rad"),
    (lambda L: L[:3] + [COLUMNS.replace(",I3_A", "")] + L[4:], 4, "receiver column count 2 (I1_A, I2_A) does not match"),
    (lambda L: L[:3] + [COLUMNS.replace("I3_A", "I4_A")] + L[4:], 4, "missing receiver column I3_A"),
    (lambda L: L[:3] + [COLUMNS + ",x_m"] + L[4:], 4, "column 'x_m' appears twice"),
    (lambda L: L + [ROW1.replace("-0.3750", "abc")], 7, "non-numeric value 'abc' in column x_m"),
    (lambda L: L + [ROW1.replace("-0.3750", "")], 7, "empty value in column x_m"),
    (lambda L: L + [ROW1.replace("6.5500e-04", "nan")], 7, "non-finite value 'nan' in column I2_A"),
    (lambda L: L + [ROW1.replace("6.5500e-04", "-inf")], 7, "non-finite value '-inf' in column I2_A"),
    (lambda L: L + [ROW1.replace("20.01", "hot")], 7, "non-numeric value 'hot' in column temp_C"),
    (lambda L: L + [ROW1.replace("0.100", "0.050")], 7, "time goes backwards: t_s = 0.050 after 0.100"),
    (lambda L: L + [ROW1 + ",1"], 7, "11 fields, the column row has 10"),
    (lambda L: L + [""], 7, "empty line in the data"),
    (lambda L: L + ["# late comment"], 7, "comment line after the column row"),
    (lambda L: L[:3], 4, "the file ends before the column row"),
])
def test_every_refusal_names_file_line_and_reason(tmp_path, mutate, line, reason):
    path = _write(tmp_path, mutate(_good()))
    with pytest.raises(BenchLogError) as info:
        read_bench_log(path)
    err = info.value
    assert err.file == str(path) and err.line == line and reason in err.reason, str(err)
    assert str(err).startswith(f"{path}, line {line}: ")


def test_windows_line_ends_and_bad_utf8_are_refused(tmp_path):
    p = tmp_path / "crlf.csv"
    p.write_bytes("\r\n".join(_good()).encode() + b"\r\n")
    with pytest.raises(BenchLogError, match=r"line 1: line ends must be \\n"):
        read_bench_log(p)
    p = tmp_path / "latin.csv"
    p.write_bytes(("\n".join(_good()) + "\n").encode().replace(b"a comment", b"caf\xe9"))
    with pytest.raises(BenchLogError, match="line 3: not UTF-8"):
        read_bench_log(p)


def test_pass_column_must_hold_integers(tmp_path):
    lines = ["# esense-bench-log 1", META, COLUMNS + ",pass", ROW0 + ",0", ROW1 + ",1.5"]
    with pytest.raises(BenchLogError, match="line 5: pass must be an integer"):
        read_bench_log(_write(tmp_path, lines))


def _frame(n=5, t0=0.0):
    return pd.DataFrame({
        "t_s": t0 + 0.1 * np.arange(n), "x_m": np.linspace(-0.38, 0.38, n), "y_m": 0.0, "z_m": 0.0,
        "yaw_rad": 0.0, "U_V": 1.0, "I1_A": 1e-3 * (1 + np.arange(n) / 7), "I2_A": 6.5e-4, "I3_A": 5.1e-4,
    })


def test_write_read_round_trip_is_exact(tmp_path):
    df = _frame(7)
    df["I2_A"] = np.random.default_rng(0).normal(6.5e-4, 1e-6, 7)
    p = write_bench_log(tmp_path / "r.csv", META_DICT, df, comments=["synthetic"])
    log = read_bench_log(p)
    pd.testing.assert_frame_equal(log.data, df)
    assert log.meta == META_DICT
    with pytest.raises(FileExistsError):
        write_bench_log(p, META_DICT, df)
    write_bench_log(p, META_DICT, df.iloc[:3], overwrite=True)
    assert len(read_bench_log(p)) == 3


@pytest.mark.parametrize("change, message", [
    (lambda d: d.assign(x_m=np.nan), "non-finite value"),
    (lambda d: d.assign(t_s=d.t_s[::-1].to_numpy()), "time goes backwards"),
    (lambda d: d.drop(columns="I3_A"), "receiver column count 2"),
])
def test_writer_refuses_what_the_reader_would_refuse(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        write_bench_log(tmp_path / "bad.csv", META_DICT, change(_frame()))
    assert not (tmp_path / "bad.csv").exists()


def test_streaming_writer_appends_and_recovers_a_cut_line(tmp_path):
    p = tmp_path / "s.csv"
    with BenchLogWriter(p, META_DICT) as w:
        w.write([0.0, -0.38, 0.0, 0.0, 0.0, 1.0, 1e-3, 6e-4, 5e-4])
        w.write({"t_s": 0.1, "x_m": -0.37, "y_m": 0, "z_m": 0, "yaw_rad": 0, "U_V": "1.000000",
                 "I1_A": "1.0314e-03", "I2_A": 6e-4, "I3_A": 5e-4})
        with pytest.raises(ValueError, match="time goes backwards"):
            w.write([0.05, -0.36, 0, 0, 0, 1, 1e-3, 6e-4, 5e-4])
        with pytest.raises(ValueError, match="non-finite"):
            w.write([0.2, float("inf"), 0, 0, 0, 1, 1e-3, 6e-4, 5e-4])
        with pytest.raises(ValueError, match="not a plain finite number"):
            w.write([0.2, " 1.0", 0, 0, 0, 1, 1e-3, 6e-4, 5e-4])
    assert "1.0314e-03" in p.read_text()  # text given by a device is kept verbatim
    with pytest.raises(FileExistsError):
        BenchLogWriter(p, META_DICT)
    with open(p, "a") as f:
        f.write("0.2,-0.36,0.0,0")  # a crash in the middle of a record
    with BenchLogWriter(p, META_DICT, append=True) as w:
        assert w.recovered_tail == "0.2,-0.36,0.0,0" and w.last_t_s == 0.1
        w.write([0.3, -0.35, 0, 0, 0, 1, 1e-3, 6e-4, 5e-4])
    log = read_bench_log(p)
    assert log.warnings == [] and log.t_s.tolist() == [0.0, 0.1, 0.3]
    other = dict(META_DICT, sigma_S_per_m=0.05)
    with pytest.raises(BenchLogError, match="meta differs on sigma_S_per_m"):
        BenchLogWriter(p, other, append=True)


def test_several_files_become_passes(tmp_path):
    a = write_bench_log(tmp_path / "a.csv", META_DICT, _frame(4))
    b_frame = _frame(3)
    b_frame["pass"] = [4, 4, 9]
    b = write_bench_log(tmp_path / "b.csv", META_DICT, b_frame)
    log = read_bench_logs([a, b])
    assert log.passes.tolist() == [0, 0, 0, 0, 1, 1, 2]
    assert log.data["file"].tolist() == ["a.csv"] * 4 + ["b.csv"] * 3
    assert log.pass_numbers.tolist() == [0, 1, 2] and len(log.select_pass(1)) == 2
    c = write_bench_log(tmp_path / "c.csv", dict(META_DICT, tank_m=None), _frame(2))
    with pytest.raises(BenchLogError, match="c.csv, line 2: not the same run as a.csv: the meta differs on tank_m"):
        read_bench_logs([a, c])


# ------------------------------------------------- the reader never changes a number
@pytest.mark.parametrize("value, words", [
    ("1_0", "underscore"),
    (" 1.0 ", "spaces around it"),
    ("1.0 ", "spaces around it"),
    ("0x10", "non-numeric"),
    ("1e400", "overflows a double"),
    ("nan", "non-finite"),
    ("", "empty value"),
])
def test_a_number_written_otherwise_than_plainly_is_refused(tmp_path, value, words):
    row = ROW1.split(",")
    row[7] = value  # I2_A
    lines = _good([]) [:-1] + [",".join(row)]
    with pytest.raises(BenchLogError, match=words) as info:
        read_bench_log(_write(tmp_path, lines))
    assert info.value.line == 6


@pytest.mark.parametrize("value", ["1", "-0.5", "+.5", "1.", "1.0314e-03", "2E+5"])
def test_plain_decimal_forms_are_read_exactly(tmp_path, value):
    row = ROW1.split(",")
    row[7] = value
    log = read_bench_log(_write(tmp_path, _good()[:-1] + [",".join(row)]))
    assert log.currents_A[1, 1] == float(value)


def test_a_pass_that_overflows_is_refused_not_warned(tmp_path, recwarn):
    lines = ["# esense-bench-log 1", META, COLUMNS + ",pass", ROW0 + ",0", ROW1 + ",1e20"]
    with pytest.raises(BenchLogError, match="out of range") as info:
        read_bench_log(_write(tmp_path, lines))
    assert info.value.line == 5 and len(recwarn) == 0


def test_a_meta_key_given_twice_is_refused(tmp_path):
    meta = META[:-1] + ', "sigma_S_per_m": 0.05}'
    with pytest.raises(BenchLogError, match="'sigma_S_per_m' appears twice") as info:
        read_bench_log(_write(tmp_path, ["# esense-bench-log 1", meta] + _good()[2:]))
    assert info.value.line == 2


def test_a_byte_order_mark_is_named(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + ("\n".join(_good()) + "\n").encode())
    with pytest.raises(BenchLogError, match="byte-order mark") as info:
        read_bench_log(p)
    assert info.value.line == 1
    from electrosense.validation.bench.log import read_header
    with pytest.raises(BenchLogError, match="byte-order mark"):
        read_header(p)


def test_cr_only_line_ends_are_named(tmp_path):
    p = tmp_path / "mac.csv"
    p.write_bytes(("\r".join(_good()) + "\r").encode())
    with pytest.raises(BenchLogError, match="CR-only"):
        read_bench_log(p)
    from electrosense.validation.bench.log import read_header
    with pytest.raises(BenchLogError, match="CR-only"):
        read_header(p)


def test_a_trailing_space_on_line_1_is_named_not_called_a_version(tmp_path):
    with pytest.raises(BenchLogError, match="no trailing space") as info:
        read_bench_log(_write(tmp_path, ["# esense-bench-log 1 "] + _good()[1:]))
    assert "version" not in info.value.reason
