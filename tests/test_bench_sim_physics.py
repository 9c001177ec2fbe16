"""The virtual bench: trajectories, the bench's noise, and each physical effect built into the physics."""

import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.bem.conductance import ConductanceMatrix
from electrosense.meshes.objects import Sphere
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.virtual import BenchNoise, Effects, VirtualBench, parse_path, repeat_passes
from electrosense.validation.bench.virtual.trajectory import grid, wall_to_wall

NO_NOISE = BenchNoise(current_rel=0.0, position_m=0.0)


class RecordingModel:
    """Stand-in for validation.simulation.models.simulate that remembers how it was called; K does not depend on the pose."""

    def __init__(self):
        self.calls = []

    def __call__(self, model, sensor, poses, tank, sigma_S_per_m, objects=(), psm_model=None,
                 contact_impedance_ohm_m2=None, **options):
        self.calls.append(dict(model=model, poses=np.array(poses), tank=tank, sigma=sigma_S_per_m, objects=objects,
                               z_c=contact_impedance_ohm_m2, options=options))
        n = sensor.n_electrodes
        K = sigma_S_per_m * 0.03 * (n * np.eye(n) - np.ones((n, n)))
        return ConductanceMatrix(np.broadcast_to(K, (len(poses), n, n)).copy(), sensor.emitter, sigma_S_per_m)


def bench(effects=(), noise=NO_NOISE, sensor="angels-4", seed=0):
    """A bench whose model is evaluated at every true pose (the PSM path; the BEM path has its own test)."""
    model = RecordingModel()
    b = VirtualBench(preset(sensor), Tank((1.0, 1.0, 1.0)), 0.0354, model="psm", effects=Effects.parse(effects),
                     noise=noise, seed=seed, simulate=model)
    return b, model


def test_wall_to_wall_follows_the_paper():
    p = wall_to_wall((1.0, 1.0, 1.0))
    assert p.shape == (161, 4)
    np.testing.assert_allclose(p[[0, -1], 0], [-0.37, 0.37])
    np.testing.assert_array_equal(p[:, 1:], 0.0)  # y = 0, mid-plane, yaw 0 (head to +x)
    np.testing.assert_allclose(np.diff(p[:, 0]), 0.74 / 160)
    np.testing.assert_allclose(wall_to_wall((2.0, 1.0, 1.0), n=3)[:, 0], [-0.87, 0.0, 0.87])


def test_paths_and_passes():
    g = grid((-0.1, 0.1, 3), (0.0, 0.2, 2), z_m=0.05)
    np.testing.assert_allclose(g[:, 0], [-0.1, 0.0, 0.1, 0.1, 0.0, -0.1])  # serpentine
    np.testing.assert_allclose(g[:, 2], 0.05)
    line = parse_path("line:0,0,0,0:0.2,0.1,0,1.5:5")
    np.testing.assert_allclose(line[-1], [0.2, 0.1, 0.0, 1.5])
    poses, passes = repeat_passes(line, 3)
    assert passes.tolist() == [0] * 5 + [1] * 5 + [2] * 5
    np.testing.assert_array_equal(poses[5:10], line[::-1])  # back ...
    np.testing.assert_array_equal(poses[10:], line)          # ... and forth
    for bad, msg in [("spiral", "unknown kind"), ("line:0,0,0:1,1,1,1:3", "needs 4 numbers"),
                     ("grid:0,1", "grid:X0,X1,NX")]:
        with pytest.raises(ValueError, match=msg):
            parse_path(bad)


def test_effect_parsing_refuses_unknown_names_and_bad_values():
    with pytest.raises(ValueError, match="unknown effect 'salinity'"):
        Effects.parse(["salinity=3"])
    with pytest.raises(ValueError, match="expected 4 numbers"):
        Effects.parse(["pose_offset=0.001,0"])
    with pytest.raises(ValueError, match="unmodelled_object"):
        Effects.parse(["unmodelled_object=cube,0,0,0,1"])
    with pytest.raises(ValueError, match="2 gains for 3 receivers"):
        bench(["channel_gain=1,1"])


def test_without_effects_the_bench_measures_the_model_at_the_logged_pose():
    b, model = bench()
    poses = wall_to_wall(n=11)
    run = b.run(poses, rate_hz=5.0, U_V=2.0)
    call = model.calls[0]
    assert call["sigma"] == 0.0354 and call["tank"] == Tank((1.0, 1.0, 1.0)) and call["objects"] == ()
    np.testing.assert_array_equal(call["poses"], poses)
    K = model(call["model"], preset("angels-4"), poses[:1], None, 0.0354)
    np.testing.assert_allclose(run.currents_A, np.broadcast_to(K.receiver_currents_A(2.0), (11, 3)))
    np.testing.assert_allclose(run.t_s, np.arange(11) / 5.0)
    assert np.all(run.currents_A > 0)  # bench sign: into the receivers


def test_each_effect_goes_where_the_physics_puts_it():
    poses = wall_to_wall(n=21)
    base, _ = bench()
    ref = base.run(poses).currents_A

    b, m = bench(["conductivity=-2%"])
    run = b.run(poses)
    assert m.calls[0]["sigma"] == pytest.approx(0.0354 * 0.98)
    np.testing.assert_allclose(run.currents_A / ref, 0.98)  # K is proportional to sigma

    b, m = bench(["pose_offset=0.002,-0.001,0,0.01"])
    run = b.run(poses)
    np.testing.assert_allclose(m.calls[0]["poses"] - poses, np.broadcast_to([0.002, -0.001, 0, 0.01], (21, 4)))
    np.testing.assert_array_equal(run.poses, poses)  # the log keeps the nominal pose

    b, m = bench(["tank_size=1.2,0.8,1.0", "water_depth=0.7"])
    b.run(poses)
    assert m.calls[0]["tank"] == Tank((1.2, 0.8, 1.0), 0.7)

    b, m = bench(["contact_impedance=0.05", "unmodelled_object=sphere,0.1,0.08,0,0.02,conducting"])
    b.run(poses)
    assert m.calls[0]["z_c"] == 0.05
    (obj,) = m.calls[0]["objects"]
    assert isinstance(obj, Sphere) and obj.is_conducting and obj.centre_m == (0.1, 0.08, 0.0)

    b, _ = bench(["channel_gain=1.01,0.99,1.0"])
    np.testing.assert_allclose(b.run(poses).currents_A / ref, np.broadcast_to([1.01, 0.99, 1.0], (21, 3)))

    b, _ = bench(["temperature_drift=0.5"])
    run = b.run(poses)
    np.testing.assert_allclose(run.temp_C[[0, -1]], [20.0, 20.5])
    np.testing.assert_allclose(run.currents_A[-1] / ref[-1], 1.0 + 0.02 * 0.5)  # 2 %/K
    np.testing.assert_allclose(run.sigma_true_S_per_m[-1], 0.0354 * 1.01)


def test_the_bench_noise_has_the_papers_size():
    b, m = bench(noise=BenchNoise(), seed=3)
    poses = np.zeros((4000, 4))
    run = b.run(poses)
    exact, _ = bench()
    ref = exact.run(poses[:1]).currents_A[0]
    rel = run.currents_A / ref - 1.0
    assert abs(rel.std() - 5e-4) < 0.05 * 5e-4 and abs(rel.mean()) < 5e-5
    dx = m.calls[0]["poses"][:, :3] - poses[:, :3]
    assert abs(dx.std() - 1e-4) < 0.05 * 1e-4
    np.testing.assert_array_equal(m.calls[0]["poses"][:, 3], 0.0)


def test_out_of_the_water_is_refused():
    b, _ = bench(["tank_size=0.5,1,1"])
    with pytest.raises(ValueError, match="out of the water"):
        b.run(wall_to_wall(n=5))


def test_with_the_real_psm_the_conductivity_offset_is_exact():
    from electrosense.psm import PolySphericalModel, conductance

    psm_model = PolySphericalModel.collinear([0.0071, 0.0071], [0.2])
    tank = Tank((1.0, 1.0, 1.0))
    poses = wall_to_wall(n=9)
    run = VirtualBench(preset("angels-2"), tank, 0.0354, model="psm", psm_model=psm_model, noise=NO_NOISE,
                       effects=Effects.parse(["conductivity=-2.06%"])).run(poses)
    direct = conductance(psm_model, poses, 0.0354, tank=tank).receiver_currents_A(1.0)
    np.testing.assert_allclose(run.currents_A, direct * (1 - 0.0206), rtol=1e-12)
    R = 1.0 / run.currents_A[:, 0]
    assert R[4] < R[0] and R[4] < R[-1]  # the resistance rises towards the walls (paper, fig. 6)


def test_cli_writes_a_simulated_log(tmp_path):
    from electrosense.psm import PolySphericalModel
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.cli import main

    model_file = tmp_path / "electrosense.psm.json"
    PolySphericalModel.collinear([0.0071, 0.0071], [0.2]).save(model_file)
    out = tmp_path / "sim.csv"
    args = ["bench-sim", "-o", str(out), "--sensor", "angels-2", "--model", "psm", "--psm-model", str(model_file), "--passes", "2",
            "--path", "wall-to-wall:21", "--effect", "conductivity=-2%", "--seed", "1"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    log = read_bench_log(out)
    assert len(log) == 42 and log.pass_numbers.tolist() == [0, 1]
    assert "SIMULATED" in log.meta["source"] and "conductivity=-2%" in log.meta["source"]
    assert log.sigma_S_per_m == 0.0354  # the meta keeps the nominal conductivity
    np.testing.assert_allclose(log.poses[:21, 0], np.linspace(-0.37, 0.37, 21), atol=5e-5)
    again = CliRunner().invoke(main, args)
    assert again.exit_code != 0 and "exists" in again.output
    bad = CliRunner().invoke(main, ["bench-sim", "-o", str(tmp_path / "x.csv"), "--faults", "all"])
    assert bad.exit_code != 0 and "--faults need a serial line" in bad.output


class PoseDependentModel(RecordingModel):
    """K grows with x: as a different function of the pose for the 'bem' and the 'psm'."""

    def __call__(self, model, sensor, poses, tank, sigma_S_per_m, **kwargs):
        C = super().__call__(model, sensor, poses, tank, sigma_S_per_m, **kwargs)
        x = np.asarray(poses)[:, 0]
        factor = (1.0 + 0.5 * x**2) if model == "bem" else (1.0 + 0.2 * x)
        return ConductanceMatrix(C.K_S * factor[:, None, None], C.emitter, C.sigma_S_per_m)


def test_bem_physics_once_per_distinct_pose_and_the_robot_noise_carried_by_the_psm():
    model = PoseDependentModel()
    b = VirtualBench(preset("angels-2"), Tank((1.0, 1.0, 1.0)), 0.0354, noise=BenchNoise(0.0, 1e-3), seed=3,
                     simulate=model)
    assert b.model == "bem"   # the bench's physics is the BEM unless the user says otherwise
    poses, passes = repeat_passes(wall_to_wall(n=7), 3)
    run = b.run(poses, passes=passes)
    bem_calls = [c for c in model.calls if c["model"] == "bem"]
    assert len(bem_calls) == 1 and len(bem_calls[0]["poses"]) == 7    # three passes, seven distinct poses
    x_true, x_nominal = run.true_poses[:, 0], run.poses[:, 0]
    I_nominal = 0.0354 * 0.03 * (1 + 0.5 * x_nominal**2)                # the 'bem' at the nominal pose ...
    expected = I_nominal * (1 + 0.2 * x_true) / (1 + 0.2 * x_nominal)  # ... moved by the 'psm' to the true pose
    np.testing.assert_allclose(run.currents_A[:, 0], expected, rtol=1e-12)


def test_the_bem_physics_tank_grading_reaches_the_bem_and_the_log_says_it():
    """``--tank-grading`` (the CLI's) goes to the BEM physics as the sweep's ``tank_grading`` and is named in
    the log's source; without it the BEM's default is used and nothing is said."""
    model = PoseDependentModel()
    fine = VirtualBench(preset("angels-2"), Tank((1.0, 1.0, 1.0)), 0.0354, noise=BenchNoise(0.0, 0.0), seed=3,
                        simulate=model, tank_grading=0.15)
    fine.run(wall_to_wall(n=3))
    assert [c["options"].get("tank_grading") for c in model.calls if c["model"] == "bem"] == [0.15]
    assert "tank mesh grading 0.15" in fine.describe()
    plain = VirtualBench(preset("angels-2"), Tank((1.0, 1.0, 1.0)), 0.0354, simulate=PoseDependentModel())
    assert "grading" not in plain.describe()


def test_wall_images_give_each_pose_its_own_tank_mesh_with_exact_near_walls(tmp_path):
    """``bench-sim --wall-images``: the BEM physics at each pose on its own tank mesh with the tank's flat faces
    near the sensor as image planes (as a tank map's BEM poses), said in the log's source; a meshed wall beside
    the sensor is what it replaces."""
    from click.testing import CliRunner

    from electrosense.bem import PoseSweep
    from electrosense.bem.conductance import ConductanceMatrix
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.cli import main
    from electrosense.validation.simulation.tank_map import IMAGE_FACES_WITHIN_M, each_on_its_own_tank_mesh

    out = tmp_path / "wall.csv"
    r = CliRunner().invoke(main, ["bench-sim", "-o", str(out), "--sensor", "angels-2", "--tank", "0.5,0.4,0.3",
                                  "--path", "line:-0.1,0.16,0,0:0.1,0.16,0,0:2", "--wall-images", "--edge-length",
                                  "0.02", "--tank-grading", "0.3", "--seed", "1"])
    assert r.exit_code == 0, r.output
    log = read_bench_log(out)
    assert "each pose its own tank mesh, the flat faces within 0.08 m image planes" in log.meta["source"]
    assert "sensor mesh edge 0.02 m" in log.meta["source"]
    sweep = PoseSweep(preset("angels-2"), Tank((0.5, 0.4, 0.3)), (), 0.0354, edge_length_m=0.02, tank_grading=0.3)
    K = each_on_its_own_tank_mesh(sweep, np.array([[-0.1, 0.16, 0, 0], [0.1, 0.16, 0, 0]]), IMAGE_FACES_WITHIN_M)
    expected = ConductanceMatrix(K, 2, 0.0354).receiver_currents_A(1.0)
    # the bench's noise on the currents (0.05 %) and the robot's 0.1 mm carried by the PSM's change
    np.testing.assert_allclose(log.currents_A, expected, rtol=5e-3)
    meshed = PoseSweep(preset("angels-2"), Tank((0.5, 0.4, 0.3)), (), 0.0354, edge_length_m=0.02,
                       tank_grading=0.3).conductance(np.array([[-0.1, 0.16, 0, 0]])).K_S
    assert not np.allclose(meshed, K[:1], rtol=1e-6)     # the physics is not the one-mesh default


def test_cli_log_names_a_users_sensor_file_inside_its_folder(tmp_path):
    """A sensor file given by any path: the log names it relative to its own folder where it lies there, else a
    copy beside the log (a path in a log never leads out of its folder); a copy that would overwrite another
    sensor's file is refused before any work, and the file left as it was."""
    import dataclasses

    from electrosense.meshes.sensor import load_sensor, preset, save_sensor
    from electrosense.psm import PolySphericalModel
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.cli import main

    model_file = tmp_path / "m.psm.json"
    PolySphericalModel.collinear([0.0071, 0.0071], [0.2]).save(model_file)
    probe = dataclasses.replace(preset("angels-2"), name="my-probe")
    (tmp_path / "sensors").mkdir()
    save_sensor(probe, tmp_path / "sensors" / "probe.json")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()

    def sim(out, sensor_file):
        return CliRunner().invoke(main, ["bench-sim", "-o", str(out), "--sensor", str(sensor_file), "--model", "psm",
                                         "--psm-model", str(model_file), "--path", "wall-to-wall:5"])

    inside = sim(tmp_path / "in.csv", (tmp_path / "sensors" / "probe.json").resolve())
    assert inside.exit_code == 0, inside.output
    assert read_bench_log(tmp_path / "in.csv").meta["sensor"] == "sensors/probe.json"
    outside = sim(elsewhere / "out.csv", tmp_path / "sensors" / "probe.json")
    assert outside.exit_code == 0, outside.output
    log = read_bench_log(elsewhere / "out.csv")
    assert log.meta["sensor"] == "out.sensor.json" and log.sensor == probe
    other = dataclasses.replace(probe, name="another")
    save_sensor(other, elsewhere / "clash.sensor.json")
    clash = sim(elsewhere / "clash.csv", tmp_path / "sensors" / "probe.json")
    assert clash.exit_code == 1 and "describes another sensor" in clash.output and "computing" not in clash.output
    assert load_sensor(elsewhere / "clash.sensor.json") == other and not (elsewhere / "clash.csv").exists()
    nowhere = sim(tmp_path / "no such folder" / "run.csv", tmp_path / "sensors" / "probe.json")
    assert nowhere.exit_code == 1 and "does not exist" in nowhere.output and "computing" not in nowhere.output


def test_a_sweep_of_a_scene_names_the_sensor_file_the_scene_names(tmp_path):
    """`esense sweep --scene` with a sensor file: the log beside the scene names that file; a log in another
    folder, or a scene that changes the file's emitter, a copy beside the log."""
    import dataclasses

    from electrosense.meshes.sensor import preset, save_sensor
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.cli import main

    probe = dataclasses.replace(preset("angels-2"), name="my-probe")
    (tmp_path / "sensors").mkdir()
    save_sensor(probe, tmp_path / "sensors" / "probe.json")
    (tmp_path / "elsewhere").mkdir()

    def sweep(scene_text, out):
        (tmp_path / "bench.toml").write_text('[tank]\nsize_m = [0.8, 0.6, 0.4]\n[sensor]\nfile = "sensors/probe.json"\n'
                                             + scene_text)
        run = CliRunner().invoke(main, ["sweep", "--model", "psm", "--scene", str(tmp_path / "bench.toml"), "--from",
                                        "-0.1,0", "--to", "0.1,0", "--steps", "3", "--quiet", "-o", str(out)])
        assert run.exit_code == 0, run.output
        return read_bench_log(out)

    assert sweep("", tmp_path / "run.csv").meta["sensor"] == "sensors/probe.json"
    away = sweep("", tmp_path / "elsewhere" / "run.csv")
    assert away.meta["sensor"] == "run.sensor.json" and away.sensor == probe
    emitter_1 = sweep("emitter = 1\n", tmp_path / "e1.csv")
    assert emitter_1.meta["sensor"] == "e1.sensor.json" and emitter_1.sensor == probe.with_emitter(1)
