"""A cylindrical tank in a bench log: written by what simulates it, read back as that tank (not its bounding box),
refused where it contradicts itself, and the models that cannot simulate it say so before any work."""
import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log import BenchLogError, read_bench_log, read_bench_logs, write_bench_log
from electrosense.validation.bench.log.header import tank_meta
from electrosense.validation.cli import main

BASE = {"sensor": "angels-4", "emitter": 4, "sigma_S_per_m": 0.0354}


def _frame(n=12):
    return pd.DataFrame({"t_s": np.arange(n, dtype=float), "x_m": np.linspace(-0.05, 0.05, n), "y_m": 0.0,
                         "z_m": 0.0, "yaw_rad": 0.0, "U_V": 1.0, "I1_A": 1.0e-3 * (1 + np.arange(n) / 50),
                         "I2_A": 6.5e-4, "I3_A": 5.1e-4})


def _random_cylinders(seed, n):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        r, h = rng.uniform(0.1, 1.5), rng.uniform(0.1, 1.0)
        floor = r * rng.uniform(0.7, 1.3) if rng.random() < 0.5 else None
        yield CylinderTank(r, h, h * rng.uniform(0.5, 1.0), floor)


@pytest.mark.parametrize("tank", list(_random_cylinders(5, 4)) + [Tank((0.7, 0.4, 0.3), 0.25), None])
def test_the_tank_written_is_the_tank_read(tmp_path, tank):
    path = write_bench_log(tmp_path / "run.csv", {**BASE, **tank_meta(tank)}, _frame())
    log = read_bench_log(path)
    assert log.tank == tank
    if isinstance(tank, CylinderTank):     # a reader that knows only boxes still sees its extent
        lo, hi = tank.water_bounds_m
        d = json.loads(path.read_text().splitlines()[1][len("# meta: "):])["tank_m"]
        assert d[0] == d[1] == pytest.approx(2 * max(tank.radius_m, tank.floor_radius_m)) and d[2] == tank.height_m
        assert d[0] >= hi[0] - lo[0] - 1e-12


@pytest.mark.parametrize("cylinder, tank_m, reason", [
    ({"radius_m": 0.2}, [0.5, 0.5, 0.3], "'tank_m' [0.5, 0.5, 0.3] is not the bounding box of the cylinder"),
    ({"radius_m": 0.2, "floor_radius_m": 0.25}, [0.4, 0.4, 0.3], "is not the bounding box"),
    ({"radius": 0.2}, [0.4, 0.4, 0.3], "unknown key(s) 'radius'"),
    ({"floor_radius_m": 0.2}, [0.4, 0.4, 0.3], "lacks 'radius_m'"),
    ({"radius_m": -0.2}, [0.4, 0.4, 0.3], "'radius_m' must be a positive length"),
    (0.2, [0.4, 0.4, 0.3], "must be an object"),
    ({"radius_m": 0.2}, None, "'tank_m' is null (unbounded water)"),
])
def test_a_cylinder_that_contradicts_itself_is_refused_on_line_2(tmp_path, cylinder, tank_m, reason):
    meta = {**BASE, "tank_m": tank_m, "tank_cylinder": cylinder}
    path = tmp_path / "bad.csv"
    path.write_text("# esense-bench-log 1\n# meta: " + json.dumps(meta) + "\n" + _frame(2).to_csv(index=False))
    with pytest.raises(BenchLogError) as info:
        read_bench_log(path)
    assert info.value.line == 2 and reason in info.value.reason, str(info.value)
    with pytest.raises(ValueError, match="tank_cylinder|tank_m"):   # the writer refuses what the reader would
        write_bench_log(tmp_path / "w.csv", meta, _frame(2))
    assert not (tmp_path / "w.csv").exists()


def test_a_box_and_a_cylinder_in_the_same_bounding_box_are_not_one_run(tmp_path):
    cylinder = CylinderTank(0.25, 0.3)
    a = write_bench_log(tmp_path / "a.csv", {**BASE, **tank_meta(cylinder)}, _frame())
    b = write_bench_log(tmp_path / "b.csv", {**BASE, **tank_meta(Tank((0.5, 0.5, 0.3)))}, _frame())
    with pytest.raises(BenchLogError, match="the meta differs on tank_cylinder"):
        read_bench_logs([a, b])


def test_models_that_cannot_simulate_a_cylinder_say_so_before_any_work(tmp_path):
    from electrosense.psm.images import image_sources

    with pytest.raises(ValueError, match="the PSM's images are a box tank's"):
        image_sources(CylinderTank(0.25, 0.3))
    log = write_bench_log(tmp_path / "cyl.csv", {**BASE, **tank_meta(CylinderTank(0.25, 0.3))}, _frame())
    run = CliRunner().invoke(main, ["validate", str(log), "--models", "bem,psm", "-o", str(tmp_path / "v")])
    assert run.exit_code == 2 and "leave psm out of --models" in run.output, run.output
    run = CliRunner().invoke(main, ["diagnose", str(log), "-o", str(tmp_path / "d")])
    assert run.exit_code != 0 and "the diagnosis knows box tanks" in run.output, run.output
    assert not (tmp_path / "v").exists()
