"""``esense sweep``: bench-log CSV that reads back, resumable stores, netCDF, plots, clear errors."""
from __future__ import annotations

import time

import numpy as np
import pytest
from click.testing import CliRunner

from electrosense import psm
from electrosense.validation.cli import main


@pytest.fixture(scope="module")
def psm_file(tmp_path_factory):
    """A 4-sphere PSM of the angels-4 proportions (radii and centres of the paper's symmetric fit)."""
    model = psm.PolySphericalModel(
        radii_m=np.array([0.0072, 0.0074, 0.0074, 0.0072]),
        centres_m=np.array([[0.0769 / 2 + 0.0785, 0, 0], [0.0769 / 2, 0, 0], [-0.0769 / 2, 0, 0],
                            [-0.0769 / 2 - 0.0785, 0, 0]]),
        emitter=4,
    )
    path = tmp_path_factory.mktemp("psm") / "electrosense.psm.json"
    model.save(path)
    return path


def _run(*args):
    result = CliRunner().invoke(main, ["sweep", *map(str, args)], catch_exceptions=False)
    return result


LINE = ("--from", "-0.3,0", "--to", "0.3,0.05", "--steps", 25, "--yaw", 0.3)


def test_csv_is_a_bench_log_with_resistances(tmp_path, psm_file):
    from electrosense.validation.bench.log import read_bench_log

    out = tmp_path / "sweep.csv"
    r = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--tank", "1,0.8,0.6", "--sigma", 0.05,
             *LINE, "--workers", 1, "--quiet", "-o", out)
    assert r.exit_code == 0, r.output
    log = read_bench_log(out)
    assert log.meta["source"].startswith("esense sweep --model psm")
    assert log.sigma_S_per_m == 0.05 and log.tank.size_m == (1.0, 0.8, 0.6) and log.emitter == 4
    assert np.all(log.U_V == 1.0) and np.all(np.diff(log.t_s) > 0)
    np.testing.assert_allclose(log.poses[[0, -1]], [[-0.3, 0, 0, 0.3], [0.3, 0.05, 0, 0.3]])
    model = psm.PolySphericalModel.load(psm_file)
    direct = psm.conductance(model, log.poses, 0.05, tank=log.tank)
    np.testing.assert_allclose(log.currents_A, direct.receiver_currents_A(1.0), rtol=1e-12)
    R = log.data[["R1_ohm", "R2_ohm", "R3_ohm"]].to_numpy()
    np.testing.assert_allclose(R, 1.0 / log.currents_A, rtol=1e-12)
    assert not (tmp_path / "sweep.csv.partial.zarr").exists()  # the working store is gone once the log is written
    # an existing log is never silently replaced
    again = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", *LINE, "--workers", 1, "-o", out)
    assert again.exit_code != 0 and "exists" in again.output


def test_zarr_store_resumes_and_exports_to_netcdf(tmp_path, psm_file):
    import xarray as xr

    args = ("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--unbounded",
            "--grid", "-0.1:0.1:5,-0.1:0.1:3,0:1.5:2", "--workers", 1, "--quiet")
    r = _run(*args, "-o", tmp_path / "map.zarr")
    assert r.exit_code == 0, r.output
    again = _run(*args, "-o", tmp_path / "map.zarr")
    assert again.exit_code == 0 and "all 30 poses already computed" in again.output
    nc = _run(*args, "-o", tmp_path / "map.nc")
    assert nc.exit_code == 0, nc.output
    z, n = xr.open_zarr(tmp_path / "map.zarr"), xr.open_dataset(tmp_path / "map.nc")
    np.testing.assert_array_equal(z.K_S.values, n.K_S.values)
    assert z.attrs["model"] == "psm" and z.attrs["tank_m"] == "null" and "code_version" in z.attrs
    assert '"images": "complete"' in z.attrs["model_options"]
    # another conductivity is another sweep: the store refuses to mix them
    other = _run(*args[:-1], "--sigma", 0.1, "--quiet", "-o", tmp_path / "map.zarr")
    assert other.exit_code != 0 and "differs in: sigma_S_per_m" in other.output


def test_plot_needs_a_grid_and_writes_a_png(tmp_path, psm_file):
    bad = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", *LINE, "--plot", tmp_path / "m.png",
               "-o", tmp_path / "line.csv")
    assert bad.exit_code != 0 and "needs --grid" in bad.output
    ok = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--grid", "-0.3:0.3:9,-0.3:0.3:9",
              "--workers", 1, "--quiet", "--plot", tmp_path / "m.png", "-o", tmp_path / "map.zarr")
    assert ok.exit_code == 0, ok.output
    assert (tmp_path / "m.png").stat().st_size > 10_000


def test_bad_scheduler_is_a_clear_error_within_seconds(tmp_path, psm_file):
    t0 = time.perf_counter()
    r = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", *LINE, "--scheduler", "tcp://127.0.0.1:9",
             "-o", tmp_path / "s.csv")
    assert r.exit_code != 0
    assert "cannot reach the dask scheduler at 'tcp://127.0.0.1:9'" in r.output
    assert time.perf_counter() - t0 < 15


@pytest.mark.parametrize("args, message", [
    (("--steps", 5, "-o", "x.csv"), "give --from X0,Y0 --to X1,Y1 --steps N, or --grid"),
    (("--grid", "0:1:2,0:1:2", "--steps", 3, "-o", "x.csv"), "either --grid or --from"),
    (("--grid", "0:1:2", "-o", "x.csv"), "expected X0:X1:NX,Y0:Y1:NY"),
    (("--grid", "0:0.1:2,0:0.1:2", "-o", "x.txt"), "must end in .csv, .zarr, .nc"),
    (("--grid", "0:0.1:2,0:0.1:2", "--tank", "1,1", "-o", "x.csv"), "three lengths"),
])
def test_bad_arguments_are_named(tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    r = _run("--model", "psm", "--sensor", "angels-4", *args)
    assert r.exit_code != 0 and message in r.output, r.output


def test_a_sensor_file_travels_with_the_log(tmp_path, psm_file):
    """A sensor that is not a preset is written beside the log, so that the log reads back on its own."""
    from dataclasses import replace

    from electrosense.meshes.sensor import preset, save_sensor
    from electrosense.validation.bench.log import read_bench_log

    sensor = replace(preset("angels-4"), name="my-four", notes="moved rings")
    save_sensor(sensor, tmp_path / "mine.json")
    out = tmp_path / "logs" / "sweep.csv"
    out.parent.mkdir()
    r = _run("--model", "psm", "--psm", psm_file, "--sensor", tmp_path / "mine.json", *LINE, "--quiet", "-o", out)
    assert r.exit_code == 0, r.output
    log = read_bench_log(out)
    assert log.meta["sensor"] == "sweep.sensor.json" and log.sensor.name == "my-four"
    assert log.sensor.electrodes == sensor.electrodes


def test_bem_sweep_with_an_object_reads_back_and_rises_towards_the_walls(tmp_path):
    """A coarse BEM line in a small tank, from a scene file with a conducting ball far off the path."""
    from electrosense.validation.bench.log import read_bench_log

    scene = tmp_path / "bench.toml"
    scene.write_text('[tank]\nsize_m = [0.5, 0.4, 0.3]\n[sensor]\npreset = "angels-2"\npose = [0, 0, 0, 0]\n'
                     '[[objects]]\nshape = "sphere"\ncentre_m = [0.0, 0.15, 0.0]\nradius_m = 0.02\n'
                     'material = "conducting"\n[water]\nsigma_S_per_m = 0.05\n')
    out = tmp_path / "electrosense.bem.csv"
    r = _run("--model", "bem", "--scene", scene, "--from", "-0.1,0", "--to", "0.1,0", "--steps", 3,
             "--edge-length", 0.02, "--tank-edge-length", 0.1, "--workers", 1, "--quiet", "-o", out)
    assert r.exit_code == 0, r.output
    log = read_bench_log(out)
    assert log.meta["source"].startswith("esense sweep --model bem") and log.sigma_S_per_m == 0.05
    assert log.meta["objects"][0]["conductivity_S_per_m"] == "conducting"
    R = log.data["R1_ohm"].to_numpy()
    assert R[0] > R[1] and R[2] > R[1]  # insulating walls 5 cm from the tips raise the resistance
    assert abs(R[0] - R[2]) / R[1] < 0.01  # the set-up is mirror symmetric in x


def test_a_refused_sweep_leaves_nothing_and_a_different_rerun_is_never_blocked(tmp_path, psm_file):
    out = tmp_path / "line.csv"
    partial = tmp_path / "line.csv.partial.zarr"
    # the PSM's sphere reaches beyond the wall at this pose: refused before any store exists
    bad = _run("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--tank", "0.3,0.3,0.3",
               "--from", "-0.15,0", "--to", "0.15,0", "--steps", 5, "--quiet", "-o", out)
    assert bad.exit_code != 0 and not partial.exists() and not out.exists()
    assert "beyond the wall" in bad.output and "esense map build" in bad.output   # and where to turn instead
    # a partial store of another run (an interrupted sweep) is replaced, with a word
    args = ("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--unbounded", *LINE, "--quiet")
    r = _run(*args[:-1], "--sigma", 0.2, "--workers", 1, "--quiet", "-o", tmp_path / "other.zarr")
    assert r.exit_code == 0, r.output
    (tmp_path / "other.zarr").rename(partial)
    good = _run(*args, "-o", out)
    assert good.exit_code == 0, good.output
    assert "starting over" in good.output and out.exists() and not partial.exists()


def test_a_zarr_of_another_sweep_says_how_to_go_on_and_overwrite_replaces_it(tmp_path, psm_file):
    args = ("--model", "psm", "--psm", psm_file, "--sensor", "angels-4", "--unbounded", *LINE, "--quiet")
    assert _run(*args, "-o", tmp_path / "s.zarr").exit_code == 0
    other = _run(*args, "--sigma", 0.5, "-o", tmp_path / "s.zarr")
    assert other.exit_code != 0 and "--overwrite" in other.output
    again = _run(*args, "--sigma", 0.5, "--overwrite", "-o", tmp_path / "s.zarr")
    assert again.exit_code == 0 and "starting over" in again.output


@pytest.mark.slow
@pytest.mark.parametrize("after_s", [0.3, 3.0])
def test_ctrl_c_on_a_sweep_with_workers_is_one_clean_line_and_resumable(tmp_path, psm_file, after_s):
    """SIGINT to the whole process group, as a terminal sends it, while the store is written and the cluster starts
    (0.3 s after the store appears) and once it runs: no worker tracebacks, no zarr task left pending, the store
    kept whole. (In a tank: the PSM in unbounded water came to 300 000 poses/s and finished the grid before the
    signal.)"""
    import os
    import signal
    import subprocess
    import sys

    from electrosense.validation.simulation.sweep.store import open_sweep

    out = tmp_path / "map.csv"
    cmd = [sys.executable, "-c", "import sys; sys.argv[0] = 'esense'; from electrosense.validation.cli import main; main()",
           "sweep", "--model", "psm", "--psm", str(psm_file), "--sensor", "angels-4", "--tank", "1,1,1",
           "--grid", "-0.3:0.3:1200,-0.3:0.3:1200", "--workers", "2", "--quiet", "-o", str(out)]
    # Ctrl-C as a terminal's foreground job has it: a test run started in the background (a non-interactive
    # shell's `&`) ignores SIGINT, its children inherit that, and a sweep so started rightly keeps ignoring it
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    store = tmp_path / "map.csv.partial.zarr"
    t0 = time.monotonic()
    while not store.exists() and time.monotonic() - t0 < 60 and p.poll() is None:
        time.sleep(0.05)
    time.sleep(after_s)
    os.killpg(p.pid, signal.SIGINT)
    output, _ = p.communicate(timeout=60)
    assert p.returncode == 130, output
    assert "Traceback" not in output and "KeyboardInterrupt" not in output and "Task was destroyed" not in output
    assert "interrupted (Ctrl-C)" in output and "run the same command again to resume" in output
    assert store.exists() and not out.exists()
    assert open_sweep(store).sizes["pose"] == 1200 * 1200


def test_skip_blocked_leaves_out_the_poses_the_model_does_not_reach_and_keeps_the_rest_exact(tmp_path, psm_file):
    """A grid over a tank with a ball, wall to wall: refused whole by default (naming --skip-blocked); with
    --skip-blocked the poses where the sensor or the PSM's spheres cross a wall or the ball are NaN in the store,
    the others exactly the PSM's, the scene file's sensor height taken, and the plot drawn with them blank."""
    import xarray as xr

    from electrosense.meshes import preset
    from electrosense.meshes.objects import Sphere
    from electrosense.meshes.tank import Tank
    from electrosense.validation.simulation.models import PSMEvaluator, poses_reached
    from electrosense.validation.simulation.sweep.grid import parse_grid

    scene = tmp_path / "ball.toml"
    scene.write_text('[tank]\nsize_m = [0.6, 0.5, 0.4]\n[sensor]\npreset = "angels-4"\npose = [0, 0, -0.04, 0]\n'
                     '[[objects]]\nshape = "sphere"\ncentre_m = [0.1, 0.05, -0.04]\nradius_m = 0.03\n'
                     'material = "conducting"\n[water]\nsigma_S_per_m = 0.05\n')
    grid = "-0.3:0.3:25,-0.25:0.25:21"
    args = ("--model", "psm", "--psm", psm_file, "--scene", scene, "--grid", grid, "--yaw", 0.4, "--workers", 1,
            "--quiet")
    refused = _run(*args, "-o", tmp_path / "all.nc")
    assert refused.exit_code != 0 and "--skip-blocked" in refused.output and "Traceback" not in refused.output
    # a refusal the option does not mend (every pose refused: the PSM has no pole) does not name it
    pole = tmp_path / "pole.toml"
    pole.write_text(scene.read_text() + '[[objects]]\nshape = "cylinder"\ncentre_m = [-0.2, 0.1, -0.1]\n'
                    'radius_m = 0.02\nheight_m = 0.2\n')
    refused = _run(*args[:5], pole, *args[6:], "-o", tmp_path / "pole.nc")
    assert refused.exit_code != 0 and "spheres only" in refused.output and "--skip-blocked" not in refused.output
    out, png = tmp_path / "skip.nc", tmp_path / "skip.png"
    r = _run(*args, "--skip-blocked", "--plot", png, "-o", out)
    assert r.exit_code == 0, r.output
    ds = xr.open_dataset(out)
    poses = parse_grid(grid, yaw_rad=0.4, z_m=-0.04).poses
    np.testing.assert_allclose(np.c_[ds.x_m, ds.y_m, ds.z_m, ds.yaw_rad], poses)
    model = psm.PolySphericalModel.load(psm_file)
    tank, ball = Tank((0.6, 0.5, 0.4)), Sphere((0.1, 0.05, -0.04), float("inf"), radius_m=0.03)
    evaluator = PSMEvaluator(model, 0.05, tank, (ball,))
    reached, _ = poses_reached(evaluator, preset("angels-4"), tank, (ball,), poses)
    assert 0 < (~reached).sum() < len(poses) and f"{(~reached).sum()} of {len(poses)} poses left out" in r.output
    K = ds.K_S.values
    assert np.isnan(K[~reached]).all() and np.isfinite(K[reached]).all() and ds.computed.values.all()
    assert int(ds.attrs["blocked_poses"]) == (~reached).sum()
    direct = psm.conductance(model, poses[reached], 0.05, tank=tank, objects=(ball,))
    np.testing.assert_allclose(ds.I_A.values[reached], direct.receiver_currents_A(1.0), rtol=1e-10)
    assert png.exists()
