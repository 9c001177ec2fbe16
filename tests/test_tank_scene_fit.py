"""The scene's unknowns of a ring-electrode tank fitted across set-ups (validation/diagnosis/tank_scene_fit.py).

Scenes and data are made here: random tanks, a linear surrogate with known unknowns (no BEM), and a small
phantom of the Ottawa layout written as a .mat variant (``voltRef`` as the second Ottawa file names it, eight
electrodes, the tank narrower and the ball larger than its scene says, a multiplexer class 8 % low, on a finer
mesh than the fit's).
"""
import numpy as np
import pytest
import scipy.io

from electrosense.bem.protocol import adjacent_protocol, drive_impedances_ohm, involves_drive, transfer_impedances_ohm
from electrosense.bem.solve import solve_scene
from electrosense.meshes import Scene
from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.surface_electrodes import DiscElectrode
from electrosense.validation.comparison.transfer import DEFAULT_BALL_RADIUS_M
from electrosense.validation.diagnosis import tank_scene_fit as T


def _ring_scene(rng, n=8):
    R, H = rng.uniform(0.08, 0.15), rng.uniform(0.12, 0.3)
    z, a, phi0 = -0.5 * H + rng.uniform(0.3, 0.5) * H, rng.uniform(0.003, 0.006), rng.uniform(0, 2 * np.pi)
    tank = CylinderTank(R, H, floor_radius_m=R * rng.uniform(0.85, 1.0))
    r = float(tank.radius_at(z))
    es = [DiscElectrode((r * np.cos(phi0 + 2 * np.pi * k / n), r * np.sin(phi0 + 2 * np.pi * k / n), z), a)
          for k in range(n)]
    protocol = {"ring": list(range(1, n + 1)), "ball_radius_m": 0.1 * R, "ball_z_m": z, "A": [[0.3 * R, 0.0]]}
    return Scene(None, tank=tank, electrodes=es), protocol


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_scene_moved_keeps_its_ring_on_the_wall_and_what_leaves_the_water_is_refused(seed):
    rng = np.random.default_rng(seed)
    scene, protocol = _ring_scene(rng)
    stated = T.ring_state(scene, protocol)
    us = {u.name: u for u in T.geometry_unknowns(scene, protocol)}
    assert {u.name for u in us.values()} >= set(T.GEOMETRY_GROUPS["tank"] + T.BALL_ONLY)
    values = {n: float(rng.uniform(max(u.lower, u.value - 2 * u.step), min(u.upper, u.value + 2 * u.step)))
              for n, u in us.items()}
    moved = T.scene_at(scene, protocol, values, "A")
    t = moved.tank
    for e in moved.electrodes:          # on the wall, at the ring's new height, of the new size
        assert abs(np.hypot(*e.centre_m[:2]) - t.radius_at(e.centre_m[2])) < 1e-12
        assert abs(e.centre_m[2] - values["ring_z_m"]) < 1e-12 and e.radius_m == values["electrode_radius_m"]
    assert abs(t.radius_at(values["ring_z_m"]) - values["ring_radius_m"]) < 1e-12
    assert abs(t.wall_slope - values["wall_slope"]) < 1e-12 and t.water_depth_m == pytest.approx(values["water_depth_m"])
    (ball,) = moved.objects
    c, s = np.cos(values["frame_rotation_rad"]), np.sin(values["frame_rotation_rad"])
    x0 = protocol["A"][0][0]
    assert np.allclose(ball.centre_m, (c * x0 + values["frame_dx_m"], s * x0 + values["frame_dy_m"],
                                       values["ball_z_m"]))
    with pytest.raises(ValueError, match="water"):
        T.scene_at(scene, protocol, {"ball_z_m": stated["ring_z_m"] + 10.0}, "A")
    f, note = T.placeable_step(scene, protocol, stated, {"ring_z_m": 100.0})
    assert f == 0.0 and "refused" in note
    f, note = T.placeable_step(scene, protocol, stated, {"ball_z_m": 1.5 * values["water_depth_m"]}, ("A",))
    assert 0 < f < 1 and "shortened" in note


@pytest.mark.parametrize("common_mode", [0.01, 0.45])
def test_known_unknowns_are_recovered_within_their_standard_errors_on_a_linear_surrogate(common_mode):
    """No BEM: a random linear surrogate, data made from known geometry and instrument with noise at the floors;
    the fit finds them within 4 standard errors, and a direction the data never see is named. A common mode
    read in quadrature is found at 0.01 and at 0.45 (beyond 0.2, where the fit's bound once clipped it)."""
    rng = np.random.default_rng(5)
    n = 8
    d, m = adjacent_protocol(range(1, n + 1))
    keep = ~np.asarray(involves_drive(d, m))
    D_idx, M_idx = np.nonzero(keep)
    drive, measure = d[D_idx], m[M_idx]
    from electrosense.validation.comparison.transfer import ring_pair_places

    dp, mp = ring_pair_places(drive, list(range(1, n + 1))), ring_pair_places(measure, list(range(1, n + 1)))
    R = len(drive)
    geo = [T.Unknown("g1", 0.0, -1, 1, 0.1), T.Unknown("g2", 0.0, -1, 1, 0.1), T.Unknown("unseen", 0.0, -1, 1, 0.1)]
    inst = T.instrument_unknowns(n, ground=False)
    us = geo + inst
    names = [u.name for u in us]
    Dref = np.c_[rng.normal(0, 0.3, (R, 2)), np.zeros(R)]
    Dball = Dref + np.c_[rng.normal(0, 0.05, (R, 2)), np.zeros(R)]
    logZ = np.log(rng.uniform(0.5, 2.0, R))
    ball_logZ = logZ + rng.normal(0, 0.02, R)
    sign = np.where(rng.random(R) < 0.3, -1.0, 1.0)
    Vcm = rng.normal(0, 1.0, R)
    ref = T.SetupSurrogate(names[:3], np.zeros(3), logZ, Dref, sign, Vcm, None)
    ball = T.SetupSurrogate(names[:3], np.zeros(3), ball_logZ, Dball, sign, Vcm, None)
    truth = dict.fromkeys(names, 0.0)
    truth.update(g1=0.12, g2=-0.07, log_scale=1.3, mux_odd_odd=-0.08, common_mode_quadrature=common_mode)
    x = np.array([truth[k] for k in names])
    data = T._Data(np.ones(R), (dp // 2) % 2 == 0, 2 * (dp % 2) + mp % 2, mp, n, {"A": np.zeros(R)}, 1e-3,
                   {"A": 1e-4})
    model = T._Model(data, us, 3, ref, ball, "A")
    lr = model.log_reading(ref, x)
    data.Z_ref = np.exp(lr) * (1 + 1e-3 * rng.standard_normal(R))
    data.signals["A"] = np.exp(model.log_reading(ball, x) - lr) - 1 + 1e-4 * rng.standard_normal(R)
    fit = T._Fit(None, data, us, 3, "A", report=lambda *a: None)
    _, sf = fit.once(ref, ball)
    got = dict(zip(names, sf.x))
    for k in ("g1", "g2", "log_scale", "mux_odd_odd"):
        i = names.index(k)
        assert abs(got[k] - truth[k]) < 4 * sf.se[i] + 1e-9, (k, got[k], truth[k], sf.se[i])
    cm, se = abs(got["common_mode_quadrature"]), sf.se[names.index("common_mode_quadrature")]   # its sign is free
    if common_mode > 0.1:   # seen by the data: within 4 standard errors, and those small (the bound of 0.2 this
        assert abs(cm - common_mode) < 4 * se and se < 0.01, (cm, se)   # fit once had: 0.2 +- 0.066)
    else:                   # at 0.01 it enters the readings at 1e-4, below their noise: found near zero
        assert cm < 0.012, cm
    assert np.isnan(sf.se[names.index("unseen")])
    assert any("unseen" in d["unknowns"] for d in sf.not_separable)
    # the description's tolerance as a prior: the unseen unknown at its stated value, its standard error the
    # prior's (times the fit's noise scale), still named as what the data do not separate; the others unmoved
    us[2] = T.Unknown("unseen", 0.0, -1, 1, 0.1, prior=(0.05, 0.02))
    _, sp = fit.once(ref, ball)
    i = names.index("unseen")
    assert sp.x[i] == pytest.approx(0.05, abs=1e-6) and sp.se[i] == pytest.approx(0.02 * sp.noise_rms, rel=1e-3)
    assert sp.table()["unseen"]["set_by_prior"] and any("unseen" in d["unknowns"] for d in sp.not_separable)
    assert np.allclose(sp.x[:2], sf.x[:2], atol=0.1 * sf.se[:2].max())


#: the phantom's scene file is off by more than a hand's tolerance (the tank 6 %, the ball 25 %): its
#: ``[tolerance]`` table says so, and the fit has no prior on them
LOOSE = {"ring_radius_m": np.inf, "ball_radius_m": np.inf}


def _phantom(tmp_path, rng, noise=3e-3, crosstalk=(0.0, 0.0, 0.0, 0.0), n=8):
    """A small tank's scene, and a .mat of the Ottawa layout made by the BEM at another scene and on a finer
    mesh than the fit's (the data are not the fit's own discretisation): the tank 6 % narrower at the
    ring, the ball 25 % larger, the odd-odd class 8 % low, ``noise`` (relative) on every reading; set-ups Ref,
    Avg1 and Avg2, on a ring of ``n`` electrodes. ``crosstalk``: a fixed reading added per class of (drive, measurement) pair parity
    (even-even, even-odd, odd-even, odd-odd), in units of the reference's median reading."""
    R, H = 0.1, 0.12
    z, phi0 = -0.5 * H + 0.45 * H, rng.uniform(0, 2 * np.pi)
    scene = Scene(None, tank=CylinderTank(R, H), electrodes=[
        DiscElectrode((R * np.cos(phi0 + 2 * np.pi * k / n), R * np.sin(phi0 + 2 * np.pi * k / n), z), 0.006)
        for k in range(n)])
    protocol = {"ring": list(range(1, n + 1)), "reference": "Ref", "ball_radius_m": 0.016, "ball_z_m": z,
                "Avg1": [[0.035, 0.0]], "Avg2": [[0.0, -0.04]]}
    settings = {"bem": {"tank_edge_length_m": R / 2, "edge_fraction": 0.5, "electrode_grading": 1.0},
                "protocol": protocol}
    truth = {"ring_radius_m": 0.94 * R, "ball_radius_m": 0.02}
    d, m = adjacent_protocol(range(1, n + 1))
    k, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    gain = np.where((k % 2 == 1) & (j % 2 == 1), 0.92, 1.0)
    I_A = 4.6e-3
    finer = {**settings["bem"], "tank_edge_length_m": R / 3, "edge_fraction": 0.35}
    data = {"description": "a variant of the Ottawa layout made by the test"}
    added = None
    for name in ("Ref", "Avg1", "Avg2"):
        K = solve_scene(T.scene_at(scene, protocol, truth, None if name == "Ref" else name), 1.0,
                        **finer).conductance.K_S
        Z = np.abs(transfer_impedances_ohm(K, d, m))
        if added is None:
            added = np.asarray(crosstalk)[2 * (k % 2) + j % 2] * np.median(Z[~involves_drive(d, m)])
        vv = (Z + added) * I_A * gain * (1 + noise * rng.standard_normal((n, n)))
        vv[involves_drive(d, m)] = 0.0
        data["vv" + name] = vv.reshape(-1, 1)
        data[("voltRef" if name == "Ref" else "volts" + name)] = np.full((n, 1), I_A)
        data["curr" + name] = (drive_impedances_ohm(K, d) * I_A * rng.uniform(5, 10, n))[:, None]
    scipy.io.savemat(tmp_path / "phantom.mat", data)
    return tmp_path / "phantom.mat", scene, settings, truth


# 20 s on 2 cores: in the slow run, so that the default one stays under 10 minutes (614 s measured with it); the
# default run recovers the same unknowns on the linear surrogate above and a synthetic phantom's geometry in
# tests/test_real_tank.py
@pytest.mark.slow
def test_a_variant_phantom_the_tank_ball_and_multiplexer_found_within_their_standard_errors(tmp_path):
    """Fitted jointly on the empty tank and Avg1 of data made on a finer mesh at another scene, the ring's radius,
    the ball's and the multiplexer class are found within three of their stated uncertainties (the noise's
    standard error and the BEM's discretisation error), and the held-out set-up (Avg2), solved at the fitted
    scene, is predicted far better than at the stated one. The staged fit (the geometry from Avg1's signal alone, where a larger ball and
    a narrower tank trade off) is scored too. About 20 s."""
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.bench.transfer.log import read_transfer_log

    mat, scene, settings, truth = _phantom(tmp_path, np.random.default_rng(3))
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="unused.toml"))
    out = T.fit_tank_scene(log, scene, 1.0, settings["bem"], settings["protocol"], "Avg1", max_iterations=4,
                           geometry=("ring_radius_m", "ball_radius_m"), tolerance=LOOSE, report=lambda *a: None)
    assert out["noise"]["bem_discretisation_log_Z"] > 0 and out["noise"]["reference_per_measurement_rel"] > 1e-3
    stated = out["what_each_explains"][-3]["setups_rms_rel"]["Avg2"]     # the instrument alone, stated scene
    assert stated > 0.2
    f = out["fits"]["joint"]
    got = f["fitted"]
    for name, value in (("ring_radius_m", truth["ring_radius_m"]), ("ball_radius_m", truth["ball_radius_m"]),
                        ("mux_odd_odd", np.log(0.92))):
        se = got[name]["se_total"]         # the noise's standard error and the BEM's own error, in quadrature
        # determined: five of its standard errors from zero at least (the BEM's own error, most of se_total for the
        # multiplexer class, differs between machines: 0.0075 of a log-gain of 0.083 with numpy 2.4 and scipy
        # 1.17, the class found 0.0009 from its truth, where the bound of a tenth passed on the CI machine)
        assert 0 < got[name]["se"] <= se < 0.2 * abs(value), (name, got[name])
        assert abs(got[name]["value"] - value) < 3 * se, (name, got[name], value)
    assert f["scores"]["setups"]["Avg2"]["held_out"] and not f["scores"]["setups"]["Avg1"]["held_out"]
    assert f["scores"]["setups"]["Avg2"]["rms_rel"] < 0.4 * stated
    assert f["scores"]["empty_heldout_rms_rel"] < 3 * out["noise"]["reference_per_measurement_rel"]
    assert out["fits"]["staged"]["fitted"]["ball_radius_m"]["se_total"] > 0    # from the geometry's own stage
    staged = out["fits"]["staged"]["scores"]
    assert staged["setups"]["Avg2"]["rms_rel"] < stated
    assert not out["optional_instrument"]["joint"]["kept"]     # no crosstalk in the data: none in the fit
    md = T.scene_fit_markdown(out)
    assert "Fit `joint`" in md and "Fit `staged`" in md and "ring_radius_m" in md


# 25 s on 2 cores: in the slow run, so that the default one stays under 10 minutes (579 s measured with it); the
# crosstalk is named by the default run in tests/test_real_tank.py (on a file that names its arrays otherwise)
@pytest.mark.slow
def test_a_multiplexer_crosstalk_enters_the_scene_fit_where_the_fitted_scene_needs_it(tmp_path):
    """The variant phantom with a fixed reading added per parity class (up to 6 % of the median reading, so
    relative to the far side's readings several times that): at the scene fitted without it the crosstalk lowers
    the BIC and enters; the empty tank's held-out drives then come within twice their floor, and the ring's
    radius within three of its standard errors. About 30 s."""
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.bench.transfer.log import read_transfer_log

    mat, scene, settings, truth = _phantom(tmp_path, np.random.default_rng(4), crosstalk=(0.0, 0.06, 0.06, -0.03),
                                           n=16)     # on 8 electrodes the classes' gains and offsets barely part
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="unused.toml"))
    out = T.fit_tank_scene(log, scene, 1.0, settings["bem"], settings["protocol"], "Avg1", max_iterations=2,
                           geometry=("ring_radius_m", "ball_radius_m"), tolerance=LOOSE, report=lambda *a: None)
    chosen = out["optional_instrument"]["joint"]
    assert chosen["kept"] and chosen["bic_with"] < chosen["bic_without"] - 10
    f = out["fits"]["joint"]
    assert f["scores"]["empty_heldout_rms_rel"] < 2 * out["noise"]["reference_per_measurement_rel"]
    got = f["fitted"]["ring_radius_m"]
    assert abs(got["value"] - truth["ring_radius_m"]) < 3 * got["se_total"], got
    xt = [f["fitted"][f"crosstalk_{c}"]["value"] for c in T.PARITY_CLASSES]
    assert xt[1] > 0 and xt[2] > 0 and xt[3] < 0 and abs(xt[0]) < 0.3 * xt[1]


def test_a_scene_fit_that_stops_leaves_the_comparison_written(tmp_path):
    """The study's scene fit on a set-up the log does not have stops with its reason in metrics.json and the
    report; the comparison before it is written all the same (no traceback). A protocol without the balls'
    radius takes a golf ball's, as the comparison does, and the fit runs to its end on this tank, whose floating
    disc sits above a ring electrode (a fitted move on the surrogate that would make them overlap once ended it:
    the scene is now solved at the placeable part of that move, and said)."""
    import json

    from test_real_tank import _synthetic_phantom

    from electrosense.validation.cli.transfer_logs import run_transfer_comparison

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(2))
    bad = tmp_path / "bad_tolerance.toml"        # a misspelt tolerance: refused before any solve, naming it
    bad.write_text((tmp_path / "tank.toml").read_text() + "\n[tolerance]\ndepth_m = 0.01\n")
    with pytest.raises(ValueError, match=r"bad_tolerance.toml: \[tolerance\] names depth_m"):
        run_transfer_comparison(mat, bad, tmp_path / "bad", diagnose=False, scene_fit=True)
    m = run_transfer_comparison(mat, tmp_path / "tank.toml", tmp_path / "out", diagnose=False, scene_fit=True,
                                fit_setup="Avg9")
    assert "Avg9" in m["scene_fit"]["error"] and m["object_rms_rel"]["Avg1"] < 0.2
    assert "Avg9" in json.loads((tmp_path / "out" / "metrics.json").read_text())["scene_fit"]["error"]
    assert "Not computed" in (tmp_path / "out" / "report.md").read_text()
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.log import read_transfer_log

    log = read_transfer_log(tmp_path / "out" / "transfer_log.csv")
    settings = load_scene_settings(tmp_path / "tank.toml")
    protocol = {k: v for k, v in settings["protocol"].items() if k != "ball_radius_m"}
    out = T.fit_tank_scene(log, load_scene(tmp_path / "tank.toml"), 1.0, settings["bem"], protocol, max_iterations=1,
                           geometry=("ring_z_m", "electrode_radius_m", "ball_radius_m", "ball_z_m"),
                           report=lambda *a: None)
    assert out["stated"]["ball_radius_m"] == DEFAULT_BALL_RADIUS_M and set(out["fits"]) == {"joint", "staged"}


def test_a_ring_written_with_rounded_coordinates_is_on_the_wall():
    """A scene file lists a ring's discs with six decimals (as a user writes them): every disc is on the wall for
    the mesher, the diagnosis's moves and the scene fit alike; a disc 1 mm inside is not."""
    from electrosense.validation.diagnosis.transfer import wall_discs

    n, R = 16, 0.15
    phi = 2 * np.pi * np.arange(n) / n
    discs = [DiscElectrode((round(R * np.cos(p), 6), round(R * np.sin(p), 6), -0.02), 0.004) for p in phi]
    scene = Scene(None, tank=CylinderTank(R, 0.3, 0.26), electrodes=discs)
    assert T._ring_discs(scene, list(range(1, n + 1))) == list(range(n))
    assert [w.index for w in wall_discs(scene)] == list(range(n))
    inside = Scene(None, tank=scene.tank, electrodes=[DiscElectrode((R - 1e-3, 0.0, -0.02), 0.004), *discs[1:]])
    with pytest.raises(ValueError, match="electrode 1 is not"):
        T._ring_discs(inside, list(range(1, n + 1)))


def test_geometry_the_data_do_not_place_is_held_at_its_stated_value_where_the_bic_prefers_it():
    """A first fit that leaves an unknown without a standard error (or with a 95 % interval wider than its bounds)
    is repeated with it held at its stated value, and the fit of lower BIC kept: an unknown the data leave
    anywhere would otherwise stay where the search left it, and the held-out set-ups pay for it (a blind file of
    the pail whose stated scene met every goal: the held-out balls from 0.07 to 0.48 after the joint fit); a pair
    each unplaced alone but placed together (a larger ball in a narrower tank) fits better free, and stays free."""
    from types import SimpleNamespace

    from electrosense.validation.diagnosis.scene_fit import Unknown

    us = [Unknown("ring_radius_m", 0.15, 0.1, 0.2, 0.005), Unknown("ball_z_m", -0.02, -0.1, 0.1, 0.01),
          Unknown("wall_slope", 0.0, -0.25, 0.25, 0.02), Unknown("log_scale", 0.0, -5, 5, 0.1)]

    def fit_with(sse_held):
        calls = []

        def chord(s_ref, s_ball, fixed, ref_block, max_iterations):
            calls.append(list(fixed))
            held = len(calls) > 1
            r = np.full(100, np.sqrt((sse_held if held else 1.0) / 100))
            se = [0.002, np.nan, 0.01, 0.01] if held else [0.002, np.nan, 0.2, 0.01]
            return (SimpleNamespace(posterior_rows=lambda x, r=r: r), SimpleNamespace(se=np.array(se), x=None), None, None,
                    [], True)

        said = []
        fake = SimpleNamespace(chord=chord, unknowns=us, nG=3, report=said.append, names=[u.name for u in us])
        return T._Fit.placed_chord(fake, None, None, ["log_scale"], True, 4), calls, said

    (result, held, compared), calls, said = fit_with(sse_held=1.0)       # as good held: two parameters fewer
    assert held == ["ball_z_m", "wall_slope"] and compared["held"]      # no standard error; +-1.96 se beyond bounds
    assert calls == [["log_scale"], ["log_scale", "ball_z_m", "wall_slope"]] and "held" in said[0]
    assert compared["bic_free"] - compared["bic_held"] == pytest.approx(2 * np.log(100))
    (result, held, compared), _, said = fit_with(sse_held=2.0)          # far worse held: left free
    assert held == [] and not compared["held"] and "left free" in said[0]
    assert T.unplaced(result[1].se[:3], us[:3]) == ["ball_z_m", "wall_slope"]
