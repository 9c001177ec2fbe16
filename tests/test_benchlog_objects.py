"""Fixed objects in a bench log's meta line: written by what simulates a scene, read back as those objects,
refused where malformed (line 2, the entry named), and a tank map's fixed objects given to a log that lists
none, while a log that lists others is refused."""
import json
import re
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from electrosense.meshes import preset
from electrosense.meshes.objects import Box, Cylinder, Sphere
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log import BenchLogError, read_bench_log, write_bench_log
from electrosense.validation.bench.log.header import objects_meta
from electrosense.validation.diagnosis.observations import DiagnosisInputError, from_bench_logs
from electrosense.validation.simulation.tank_map import log_in_map_scene

BASE = {"sensor": "angels-4", "emitter": 4, "sigma_S_per_m": 0.0354, "tank_m": [0.8, 0.6, 0.4]}


def _frame(n=12):
    return pd.DataFrame({"t_s": np.arange(n, dtype=float), "x_m": np.linspace(-0.05, 0.05, n), "y_m": 0.0,
                         "z_m": 0.0, "yaw_rad": 0.0, "U_V": 1.0, "I1_A": 1.0e-3 * (1 + np.arange(n) / 50),
                         "I2_A": 6.5e-4, "I3_A": 5.1e-4})


def _random_objects(seed, n=3):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        centre = tuple(rng.uniform(-0.2, 0.2, 3))
        material = rng.choice([0.0, np.inf, rng.uniform(0.01, 2.0)])
        kind = i % 3
        if kind == 0:
            out.append(Sphere(centre, material, f"ball {i}", radius_m=rng.uniform(0.005, 0.04)))
        elif kind == 1:
            out.append(Box(centre, material, size_m=tuple(rng.uniform(0.01, 0.1, 3)), yaw_rad=rng.uniform(-3, 3)))
        else:
            out.append(Cylinder(centre, material, "pole", radius_m=rng.uniform(0.005, 0.03),
                                height_m=rng.uniform(0.05, 0.3)))
    return tuple(out)


@pytest.mark.parametrize("seed", range(4))
def test_the_objects_written_are_the_objects_read(tmp_path, seed):
    objects = _random_objects(seed)
    path = write_bench_log(tmp_path / "run.csv", {**BASE, "objects": objects_meta(objects)}, _frame())
    assert from_bench_logs([read_bench_log(path)]).objects == objects
    assert from_bench_logs([read_bench_log(write_bench_log(tmp_path / "none.csv", BASE, _frame()))]).objects == ()


@pytest.mark.parametrize("entries, reason", [
    ({"shape": "sphere"}, "must be a list of objects"),
    ([{"shape": "cone", "centre_m": [0, 0, 0]}], "entry 1: 'shape' must be one of sphere, box, cylinder"),
    ([{"shape": "sphere", "radius_m": 0.02}], "entry 1 (sphere) has no 'centre_m'"),
    ([{"shape": "sphere", "centre_m": [0, 0, 0], "radius_m": 0.02, "colour": "red"}], "unknown key(s) 'colour'"),
    ([{"shape": "sphere", "centre_m": [0, 0, 0], "radius_m": -0.02}], "'radius_m' must be a positive length"),
    ([{"shape": "sphere", "centre_m": [0, 0, 0], "radius_m": [0.02, 0.03]}], "'radius_m' must be a positive length"),
    ([{"shape": "box", "centre_m": [0, 0, 0], "size_m": [0.1, 0.1]}], "'size_m' must be 3 positive lengths"),
    ([{"shape": "cylinder", "centre_m": [0, 0, 0], "radius_m": 0.01}], "'height_m' must be a positive length"),
    ([{"shape": "sphere", "centre_m": [0, 0, 0], "radius_m": 0.02},
      {"shape": "box", "centre_m": [0, 0], "size_m": [0.1, 0.1, 0.1]}], "entry 2 (box): object"),
    ([{"shape": "cylinder", "centre_m": [0, 0, 0], "radius_m": 0.01, "height_m": 0.1,
       "conductivity_S_per_m": "copper"}], "entry 1 (cylinder): material 'copper'"),
])
def test_malformed_objects_are_refused_on_line_2_naming_the_entry(tmp_path, entries, reason):
    path = tmp_path / "bad.csv"
    path.write_text("# esense-bench-log 1\n# meta: " + json.dumps({**BASE, "objects": entries}) + "\n"
                    + _frame(2).to_csv(index=False))
    with pytest.raises(BenchLogError) as info:
        read_bench_log(path)
    assert info.value.line == 2 and reason in info.value.reason, str(info.value)


def test_a_log_takes_the_maps_fixed_objects_unless_it_lists_others(tmp_path):
    ball = Sphere((0.1, 0.1, 0.0), np.inf, radius_m=0.02)
    tank_map = SimpleNamespace(sensor=preset("angels-4"), tank=Tank((0.8, 0.6, 0.4)), objects=(ball,))
    bare = from_bench_logs([read_bench_log(write_bench_log(tmp_path / "bare.csv", BASE, _frame()))])
    assert log_in_map_scene(tank_map, bare).objects == (ball,)
    listed = write_bench_log(tmp_path / "listed.csv", {**BASE, "objects": objects_meta((ball,))}, _frame())
    assert log_in_map_scene(tank_map, from_bench_logs([read_bench_log(listed)])).objects == (ball,)
    other = write_bench_log(tmp_path / "other.csv", {**BASE, "objects": objects_meta((Sphere((0.1, 0.1, 0.0),
                                                                                                radius_m=0.02),))},
                            _frame())
    with pytest.raises(ValueError, match="the map's fixed objects are"):
        log_in_map_scene(tank_map, from_bench_logs([read_bench_log(other)]))
    with pytest.raises(ValueError, match="the map is of the tank"):
        log_in_map_scene(SimpleNamespace(**{**vars(tank_map), "tank": Tank((0.8, 0.6, 0.5))}), bare)
    with pytest.raises(DiagnosisInputError, match="disagree on the objects"):
        from_bench_logs([read_bench_log(listed), read_bench_log(tmp_path / "bare.csv")])


def test_validate_simulates_the_objects_a_log_lists_and_leaves_the_psm_out_beside_a_pole(tmp_path):
    """A PSM sweep of a scene with a ball, validated with the PSM: the ball read back from the log (before, it
    was left out and the log differed from its own model); a log that lists a pole refuses the PSM named in
    --models, in one line."""
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    scene = tmp_path / "bench.toml"
    scene.write_text('[tank]\nsize_m = [0.8, 0.6, 0.4]\n[sensor]\npreset = "angels-4"\npose = [0, 0, 0, 0]\n'
                     '[[objects]]\nshape = "sphere"\ncentre_m = [0.0, 0.09, 0.0]\nradius_m = 0.02\n'
                     'material = "conducting"\n')
    log = tmp_path / "ball.csv"
    run = CliRunner().invoke(main, ["sweep", "--model", "psm", "--scene", str(scene), "--from", "-0.1,0", "--to",
                                    "0.1,0", "--steps", "12", "--quiet", "-o", str(log)])
    assert run.exit_code == 0, run.output
    run = CliRunner().invoke(main, ["validate", str(log), "--models", "psm", "--no-potential", "-o",
                                    str(tmp_path / "v")])
    assert run.exit_code == 0, run.output
    rms = [float(v) for v in re.findall(r'"rms": ([0-9.e+-]+)', (tmp_path / "v" / "metrics.json").read_text())]
    assert rms and max(rms) < 1e-9                  # the log's own model: its ball simulated
    lines = log.read_text().splitlines()
    meta = json.loads(lines[1][len("# meta: "):])
    del meta["objects"]
    (tmp_path / "bare.csv").write_text("\n".join([lines[0], "# meta: " + json.dumps(meta), *lines[2:]]) + "\n")
    run = CliRunner().invoke(main, ["validate", str(tmp_path / "bare.csv"), "--models", "psm", "--no-potential",
                                    "-o", str(tmp_path / "b")])
    rms = [float(v) for v in re.findall(r'"rms": ([0-9.e+-]+)', (tmp_path / "b" / "metrics.json").read_text())]
    assert run.exit_code == 0 and max(rms) > 1e-4   # the ball 5 cm from the path is seen: not listed, not simulated
    pole = {**BASE, "objects": objects_meta((Cylinder((0.2, 0.2, 0.0), radius_m=0.01, height_m=0.2),))}
    other = write_bench_log(tmp_path / "pole.csv", pole, _frame())
    run = CliRunner().invoke(main, ["validate", str(other), "--models", "psm", "-o", str(tmp_path / "w")])
    assert run.exit_code != 0 and "leave psm out of --models" in run.output and "Traceback" not in run.output


def test_diagnose_refuses_a_psm_baseline_for_a_log_that_lists_a_pole(tmp_path):
    """The PSM as the diagnosis's baseline cannot hold a pole the log lists: refused in one line, naming the
    object and what to use instead, before any simulation."""
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    pole = {**BASE, "objects": objects_meta((Cylinder((0.2, 0.2, 0.0), name="PVC pole", radius_m=0.01,
                                                      height_m=0.2),))}
    log = write_bench_log(tmp_path / "pole.csv", pole, _frame())
    run = CliRunner().invoke(main, ["diagnose", str(log), "--model", "psm", "-o", str(tmp_path / "d")])
    assert run.exit_code == 2 and "object(s) 1 (PVC pole)" in run.output and "--model anchored" in run.output, \
        run.output
