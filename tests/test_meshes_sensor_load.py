"""load_sensor: a path is data; it names a regular file or is refused with a clear message."""
import os

import numpy as np
import pytest

from electrosense.meshes.sensor import Electrode, SensorDescription, load_sensor, save_sensor


def _random_sensor(rng) -> SensorDescription:
    radius = rng.uniform(0.005, 0.02)
    length = rng.uniform(8, 20) * radius
    half = length / 2
    cap = rng.uniform(1.05, 1.5) * radius
    return SensorDescription(
        "random", radius, length,
        (Electrode("cap", half - cap, half), Electrode("cap", -half, -half + cap)),
    )


def test_a_regular_file_loads(tmp_path):
    s = _random_sensor(np.random.default_rng(1))
    save_sensor(s, tmp_path / "s.json")
    assert load_sensor("s.json", relative_to=tmp_path) == s


def test_a_directory_is_refused(tmp_path):
    (tmp_path / "d.json").mkdir()
    with pytest.raises(ValueError, match="is a directory"):
        load_sensor(tmp_path / "d.json")


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_a_device_is_refused_not_read():
    with pytest.raises(ValueError, match="not a regular file"):
        load_sensor("/dev/zero")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_is_refused_without_hanging(tmp_path):
    fifo = tmp_path / "s.json"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        load_sensor(fifo)


def test_a_huge_file_is_refused(tmp_path):
    p = tmp_path / "big.json"
    with open(p, "wb") as f:
        f.truncate(4 << 20)
    with pytest.raises(ValueError, match="bytes"):
        load_sensor(p)


@pytest.mark.parametrize("text, words", [
    ("[1, 2]", "one object"),
    ("{", "not valid JSON"),
    ('{"radius_m": 0.01}', "lacks the key"),
])
def test_malformed_json_is_refused(tmp_path, text, words):
    p = tmp_path / "s.json"
    p.write_text(text)
    with pytest.raises(ValueError, match=words):
        load_sensor(p)


def test_malformed_toml_is_refused(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("radius_m = = 1")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_sensor(p)


def test_a_log_naming_a_directory_is_refused_with_line(tmp_path):
    from electrosense.validation.bench.log.errors import BenchLogError
    from electrosense.validation.bench.log.header import interpret_meta

    (tmp_path / "sub").mkdir()
    meta = {"sensor": "sub", "emitter": 2, "tank_m": [1, 1, 1], "sigma_S_per_m": 0.0354}
    with pytest.raises((BenchLogError, ValueError), match="directory"):
        interpret_meta(meta, "log.csv", folder=tmp_path)


@pytest.mark.parametrize("spec", ["../s.json", "sub/../../s.json", "ABS"])
def test_a_path_in_a_file_never_leads_out_of_its_folder(tmp_path, spec):
    s = _random_sensor(np.random.default_rng(2))
    save_sensor(s, tmp_path / "s.json")
    (tmp_path / "logs" / "sub").mkdir(parents=True)
    spec = str(tmp_path / "s.json") if spec == "ABS" else spec
    with pytest.raises(ValueError, match="outside the folder"):
        load_sensor(spec, relative_to=tmp_path / "logs")
    assert load_sensor(str(tmp_path / "s.json")) == s  # typed by the user on the command line: taken


def test_a_link_out_of_the_folder_is_refused(tmp_path):
    s = _random_sensor(np.random.default_rng(4))
    save_sensor(s, tmp_path / "s.json")
    (tmp_path / "logs").mkdir()
    os.symlink(tmp_path / "s.json", tmp_path / "logs" / "link.json")
    with pytest.raises(ValueError, match="outside the folder"):
        load_sensor("link.json", relative_to=tmp_path / "logs")
