"""Electrodes on a tank, protocols from one K, transfer logs and the EIT .mat reader (small files made here)."""
import numpy as np
import pytest
import scipy.io

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.closed_forms import newman_disc_resistance_ohm
from electrosense.bem.protocol import adjacent_protocol, drive_impedances_ohm, involves_drive, transfer_impedances_ohm
from electrosense.bem.solve import solve, solve_scene
from electrosense.meshes import Scene
from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.cylinder_tank_mesh import mesh_cylinder_tank
from electrosense.meshes.objects import Sphere
from electrosense.meshes.quality import check_mesh
from electrosense.meshes.surface_electrodes import BodyElectrode, DiscElectrode, PlateElectrode
from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.transfer import read_transfer_log, write_transfer_log
from electrosense.validation.bench.transfer.eit_mat import read_eit_mat


def _ring(rng, n, R, z, a):
    phi = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n) / n
    return [DiscElectrode((R * np.cos(p), R * np.sin(p), z), a) for p in phi]


def test_random_cylinder_tank_mesh_is_closed_and_electrodes_have_their_area():
    rng = np.random.default_rng(3)
    R, H = rng.uniform(0.08, 0.2), rng.uniform(0.1, 0.3)
    tank = CylinderTank(R, H, H * rng.uniform(0.7, 1.0))
    n = int(rng.integers(4, 9))
    es = _ring(rng, n, R, tank.floor_z_m + 0.3 * tank.water_depth_m, 0.05 * R) + [
        DiscElectrode((0.0, 0.0, tank.floor_z_m), 0.05 * R), PlateElectrode("free_surface")]
    m = mesh_cylinder_tank(tank, es, edge_length_m=R / 3, edge_fraction=0.25, electrode_grading=1.0)
    check_mesh(m, min_angle_deg=1.0, max_aspect_ratio=60.0)
    assert m.to_trimesh().is_watertight
    assert m.electrodes == tuple(range(1, n + 3))
    np.testing.assert_allclose(m.electrode_areas_m2()[:n + 1], np.pi * (0.05 * R) ** 2, rtol=2e-3)  # the rim polygon: the true area


@pytest.mark.parametrize("tank", ['shape = "cylinder"\nradius_m = 1.0\nheight_m = 1.0', "size_m = [2.0, 2.0, 1.0]"])
def test_two_sphere_electrodes_against_the_closed_form_and_a_sphere_through_the_wall_is_refused(tmp_path, tank):
    """Two metal spheres (random radius, 20 radii apart) in a large insulating tank (cylinder or box): R = (1/a - 1/d)
    / (2 pi sigma) to 1 % (the walls add about 1e-3); from a scene file; one crossing the wall is refused, named."""
    from electrosense.meshes.scene_file import load_scene
    from electrosense.meshes.scene_mesh import SceneError

    rng = np.random.default_rng(3)
    a, sigma = rng.uniform(0.005, 0.015), rng.uniform(0.1, 2.0)
    d = 20 * a
    (tmp_path / "s.toml").write_text(f"""[tank]
{tank}
[[electrodes]]
shape = "sphere"
centre_m = [{-d / 2}, 0.0, 0.0]
radius_m = {a}
[[electrodes]]
shape = "sphere"
centre_m = [{d / 2}, 0.0, 0.0]
radius_m = {a}
""")
    scene = load_scene(tmp_path / "s.toml")
    K = solve_scene(scene, sigma, tank_edge_length_m=0.15).conductance.K_S
    R = drive_impedances_ohm(K, np.array([[1, 2]]))[0]
    assert abs(R / ((1 / a - 1 / d) / (2 * np.pi * sigma)) - 1) < 0.01
    from dataclasses import replace

    out = replace(scene, electrodes=(scene.electrodes[0], BodyElectrode(Sphere((0.995, 0.0, 0.0), radius_m=0.01))))
    with pytest.raises(SceneError, match="electrode 2 \\(sphere\\) is out of the water across the wall"):
        solve_scene(out, sigma)
    from electrosense.meshes.objects import Box

    boxes = (Box((0.3, 0.0, 0.0), size_m=(0.1, 0.1, 0.1)), Box((0.38, 0.05, 0.0), size_m=(0.1, 0.1, 0.1)))
    with pytest.raises(SceneError, match="object_1 \\(box\\) and object_2 \\(box\\) intersect"):
        solve_scene(replace(scene, objects=boxes), sigma)             # no sensor: any two shapes are checked
    with pytest.raises(SceneError, match="electrode 2 \\(sphere\\) and object_1 \\(box\\) intersect"):
        solve_scene(replace(scene, objects=(Box((d / 2 + a, 0.0, 0.0), size_m=(0.02, 0.02, 0.02)),)), sigma)


def test_a_rod_electrode_and_a_ball_against_slender_body_theory(tmp_path):
    """A metal rod (random length 15-25 radii) and a ball far apart in a large box tank, from a scene file: R = 1 /
    (sigma C_rod) + 1 / (4 pi sigma b) - 1 / (2 pi sigma D), with C_rod / eps from Vainshtein's expansion of a thin
    cylinder's capacitance in Lambda = ln(L / a) (its error is O(Lambda^-3)): to 2 %."""
    from electrosense.meshes.scene_file import load_scene

    rng = np.random.default_rng(8)
    a, b, sigma = 0.004, 0.01, rng.uniform(0.2, 2.0)
    L, D = a * rng.uniform(15, 25), 0.6
    (tmp_path / "r.toml").write_text(f"""[tank]
size_m = [3.0, 3.0, 3.0]
[[electrodes]]
shape = "rod"
centre_m = [{-D / 2}, 0.0, 0.0]
radius_m = {a}
length_m = {L}
name = "rod"
[[electrodes]]
shape = "sphere"
centre_m = [{D / 2}, 0.0, 0.0]
radius_m = {b}
""")
    K = solve_scene(load_scene(tmp_path / "r.toml"), sigma, tank_edge_length_m=0.4).conductance.K_S
    lam = np.log(L / a)
    c_rod = 2 * np.pi * L / lam * (1 + (1 - np.log(2)) / lam + (1 + (1 - np.log(2)) ** 2 - np.pi ** 2 / 12) / lam ** 2)
    R = 1 / (sigma * c_rod) + 1 / (4 * np.pi * sigma * b) - 1 / (2 * np.pi * sigma * D)
    assert abs(drive_impedances_ohm(K, np.array([[1, 2]]))[0] / R - 1) < 0.02


def test_electrode_off_the_boundary_is_refused():
    with pytest.raises(ValueError, match="not on the tank's boundary"):
        mesh_cylinder_tank(CylinderTank(0.1, 0.1), [DiscElectrode((0.05, 0.0, 0.0), 0.01)])


def test_disc_in_plane_against_newman():
    from electrosense.validation.studies.disc_electrode import hemisphere_cell

    a, b = 0.01, 0.2
    cell = hemisphere_cell(a, b, edge_fraction=0.35, grading=0.5, h_far_m=0.05)
    sol = solve(WaterBoundary.from_meshes(None, tank=cell), 1.0)
    R = 1 / sol.conductance.K_S[0, 0]
    assert abs(R / newman_disc_resistance_ohm(a, 1.0, b) - 1) < 0.012


def test_protocol_reciprocity_signs_and_contact_impedance():
    rng = np.random.default_rng(5)
    tank = CylinderTank(0.1, 0.12)
    es = _ring(rng, 8, 0.1, -0.01, 0.006)
    scene = Scene(None, tank=tank, electrodes=es)
    opts = dict(tank_edge_length_m=0.04, edge_fraction=0.5, electrode_grading=1.0)
    K = solve_scene(scene, 1.0, **opts).conductance.K_S
    d, m = adjacent_protocol(range(1, 9))
    Z = transfer_impedances_ohm(K, d, m)
    np.testing.assert_allclose(Z, Z.T, rtol=5e-3)   # reciprocity (collocation: K symmetric to ~1e-3)
    assert np.all(Z[~involves_drive(d, m)] < 0)   # V(m) - V(m+1) < 0 away from the drive
    zc = 0.01
    Kc = solve_scene(scene, 1.0, contact_impedance_ohm_m2=zc, **opts).conductance.K_S
    extra = drive_impedances_ohm(Kc, d) - drive_impedances_ohm(K, d)
    # two electrodes in series, each z_c / area (the current density is not uniform: within 10 %)
    np.testing.assert_allclose(extra, 2 * zc / (np.pi * 0.006 ** 2), rtol=0.1)
    Zc = transfer_impedances_ohm(Kc, d, m)
    off = ~involves_drive(d, m)
    assert np.max(np.abs(Zc[off] / Z[off] - 1)) < 0.05   # four-electrode readings hardly see z_c


def _mat(tmp_path, n=6, swap=True):
    rng = np.random.default_rng(1)
    vv = rng.uniform(0.1, 1.0, (n, n))
    for k in range(n):
        for mm in range(n):
            if {k, (k + 1) % n} & {mm, (mm + 1) % n}:
                vv[k, mm] = 0.0
    cur = np.full((n, 1), 4.6e-3) * (1 + 1e-4 * rng.standard_normal((n, 1)))
    volt = rng.uniform(2.9, 3.9, (n, 1))
    p = tmp_path / "ph.mat"
    scipy.io.savemat(p, {"vvRef": vv.reshape(-1, 1), ("voltsRef" if swap else "currRef"): cur,
                         ("currRef" if swap else "voltsRef"): volt, "description": "test"})
    return p, vv, cur.ravel(), volt.ravel()


def test_eit_mat_reader_conventions(tmp_path):
    p, vv, cur, volt = _mat(tmp_path)
    rows, meta = read_eit_mat(p)
    assert meta["current_field"]["Ref"] == "voltsRef"
    n = 6
    assert len(rows) == n + n * (n - 3)
    drive_rows = [r for r in rows if r[1:3] == r[3:5]]
    np.testing.assert_allclose([r[5] for r in drive_rows], volt)
    r = [r for r in rows if r[1:3] == (1, 2) and r[3:5] == (5, 4)][0]   # measurement m=4 -> V5 - V4
    assert r[5] == vv[0, 3] and r[6] == cur[0]
    write_transfer_log(tmp_path / "t.csv", {"scene": "pail.toml", **meta}, rows)
    log = read_transfer_log(tmp_path / "t.csv")
    assert len(log.V_V) == len(rows) and log.setups == ("Ref",)


def test_eit_mat_reader_leaves_out_a_nonzero_drive_entry_and_says_so(tmp_path):
    p, vv, cur, volt = _mat(tmp_path)
    rows, _ = read_eit_mat(p)
    vv[0, 0] = 0.5
    scipy.io.savemat(p, {"vvRef": vv.reshape(-1, 1), "voltsRef": cur[:, None], "currRef": volt[:, None]})
    rows_now, meta = read_eit_mat(p)
    assert rows_now == rows and meta["reader_notes"] == [
        "vvRef: 1 values on measurements touching a drive electrode (their contact impedances enter): left out"]


@pytest.mark.parametrize("line,reason", [("Ref,1,1,3,4,0.1,0.001", "itself"), ("Ref,1,2,3,4,nan,0.001", "finite"),
                                         ("Ref,1,2,3,4,0.1,-1", "I_A"), ("Ref,0,2,3,4,0.1,0.001", "electrode number")])
def test_transfer_log_reader_is_strict(tmp_path, line, reason):
    p = tmp_path / "bad.csv"
    p.write_text('# esense-transfer-log 1\n# meta: {"scene": "s.toml"}\n'
                 "setup,drive_plus,drive_minus,meas_plus,meas_minus,V_V,I_A\n" + line + "\n")
    with pytest.raises(BenchLogError, match=reason) as err:
        read_transfer_log(p)
    assert err.value.line == 4


def test_transfer_log_scene_cannot_leave_its_folder(tmp_path):
    p = write_transfer_log(tmp_path / "t.csv", {"scene": "../../etc/x.toml"}, [("Ref", 1, 2, 3, 4, 0.1, 1.0)])
    with pytest.raises(BenchLogError, match="outside"):
        read_transfer_log(p).scene_path()


def _synthetic_phantom(tmp_path, rng, dz_m=None, noise=0.001):
    """A small random tank (ring of n discs, a floor electrode, a floating disc), its scene file, and a .mat of
    the phantom's layout made by the BEM with ``noise`` (relative): an empty set-up and one with a ball.
    ``dz_m`` (n,): the ring's electrodes sit that much higher in the data than the scene file says."""
    from dataclasses import replace

    from electrosense.meshes.objects import Sphere

    n, R, H = 8, rng.uniform(0.08, 0.12), rng.uniform(0.1, 0.14)
    z_ring, a, phi0 = -0.5 * H + 0.4 * H, 0.006, rng.uniform(0, 2 * np.pi)
    ball = (0.3 * R, 0.0, z_ring)
    (tmp_path / "tank.toml").write_text(f"""[tank]
shape = "cylinder"
radius_m = {R}
height_m = {H}
[electrode_ring]
n = {n}
z_m = {z_ring}
radius_m = {a}
first_angle_rad = {phi0}
[[electrodes]]
centre_m = [0.0, 0.0, {-0.5 * H}]
radius_m = 0.005
[[electrodes]]
centre_m = [{R * np.cos(phi0)}, {R * np.sin(phi0)}, {z_ring + 0.2 * H}]
radius_m = 0.004
[bem]
tank_edge_length_m = {R / 2}
edge_fraction = 0.5
electrode_grading = 1.0
[protocol]
ring = {list(range(1, n + 1))}
floating = [{n + 2}]
reference = "Ref"
ball_radius_m = 0.015
ball_z_m = {z_ring}
Avg1 = [[{ball[0]}, {ball[1]}]]
""")
    from electrosense.meshes.scene_file import load_scene, load_scene_settings

    scene = load_scene(tmp_path / "tank.toml")
    opts = load_scene_settings(tmp_path / "tank.toml")["bem"]
    if dz_m is not None:
        moved = [replace(e, centre_m=(e.centre_m[0], e.centre_m[1], e.centre_m[2] + dz))
                 for e, dz in zip(scene.electrodes, dz_m)]
        scene = replace(scene, electrodes=tuple(moved) + tuple(scene.electrodes[n:]))
    d, m = adjacent_protocol(range(1, n + 1))
    I_A = 4.6e-3
    data = {"description": "synthetic phantom made by the test"}
    for name, objects in (("Ref", ()), ("Avg1", (Sphere(centre_m=ball, radius_m=0.015),))):
        K = solve_scene(replace(scene, objects=objects), 1.0, **opts).conductance.K_S
        vv = -transfer_impedances_ohm(K, d, m) * I_A * (1 + noise * rng.standard_normal((n, n)))
        vv[involves_drive(d, m)] = 0.0
        data["vv" + name] = vv.reshape(-1, 1)
        data["volts" + name] = np.full((n, 1), I_A)                                    # swapped, as in the file
        data["curr" + name] = (drive_impedances_ohm(K, d) * I_A * rng.uniform(5, 10, n))[:, None]
    scipy.io.savemat(tmp_path / "phantom.mat", data)
    return tmp_path / "phantom.mat"


def test_esense_validate_and_diagnose_on_a_synthetic_transfer_log(tmp_path, monkeypatch):
    """End to end: .mat -> transfer log -> ``esense validate`` (comparison) and ``esense diagnose`` (candidates),
    from the installed package alone (the studies are not importable)."""
    import json
    import sys

    from click.testing import CliRunner

    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.cli import main

    for name in ("electrosense.validation.studies", "electrosense.validation.studies.real_tank"):
        monkeypatch.setitem(sys.modules, name, None)        # any import of a study now fails
    mat = _synthetic_phantom(tmp_path, np.random.default_rng(11))
    log = eit_mat_to_transfer_log(mat, tmp_path / "phantom_log.csv", scene="tank.toml")
    runner = CliRunner()
    for cmd in ("validate", "diagnose"):
        res = runner.invoke(main, [cmd, str(log), "-o", str(tmp_path / cmd)], catch_exceptions=False)
        assert res.exit_code == 0, res.output
        m = json.loads((tmp_path / cmd / "metrics.json").read_text())
        assert m["empty_heldout_rms_rel"] < 0.03                     # the data are the BEM's own, with 0.1 % noise
        assert m["empty_symmetric_floor"]["symmetries"] == 2          # the mirror through the floating disc
        assert m["empty_symmetric_floor"]["rms_rel"] < 0.01
        assert m["object_rms_rel"]["Avg1"] < 0.2
        assert ("diagnosis" in m) == (cmd == "diagnose")
        assert (tmp_path / cmd / "report.md").exists() and (tmp_path / cmd / "empty_tank.png").exists()
        assert (tmp_path / cmd / "candidates.png").exists() == (cmd == "diagnose")
    cands = m["diagnosis"]["candidates"]
    assert "electrode_angles" in cands and "current_to_electrode_9" in cands and "current_to_electrode_10" not in cands
    assert m["diagnosis"]["chosen"] == "none"          # the BEM's own data with noise: nothing to explain


def test_random_tapered_tank_mesh_and_two_rings_from_a_scene_file(tmp_path):
    """A frustum wall (narrower at the floor): closed mesh, nodes on the frustum, discs with their true area."""
    from electrosense.meshes.scene_file import load_scene

    rng = np.random.default_rng(7)
    R, H = rng.uniform(0.08, 0.2), rng.uniform(0.15, 0.3)
    Rf = R * rng.uniform(0.7, 0.95)
    (tmp_path / "t.toml").write_text(f"""[tank]
shape = "cylinder"
radius_m = {R}
floor_radius_m = {Rf}
height_m = {H}
[[electrode_ring]]
n = 6
z_m = {-0.2 * H}
radius_m = {0.04 * Rf}
[[electrode_ring]]
n = 5
z_m = {0.2 * H}
radius_m = {0.03 * Rf}
first_angle_rad = 0.3
""")
    scene = load_scene(tmp_path / "t.toml")
    tank = scene.tank
    assert len(scene.electrodes) == 11 and scene.electrodes[6].name == "ring 2 1"
    m = mesh_cylinder_tank(tank, scene.electrodes, edge_length_m=Rf / 3, edge_fraction=0.5, electrode_grading=1.0)
    check_mesh(m, min_angle_deg=1.0, max_aspect_ratio=60.0)
    tm = m.to_trimesh()
    assert tm.is_watertight
    v = m.vertices_m[np.unique(m.faces[m.region == 0])]
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), tank.radius_at(v[:, 2]), atol=1e-12)
    frustum = np.pi * H / 3 * (R ** 2 + R * Rf + Rf ** 2)
    assert abs(tm.volume / frustum - 1) < 0.02                          # chords of the curved wall
    a = np.array([e.radius_m for e in scene.electrodes])
    np.testing.assert_allclose(m.electrode_areas_m2(), np.pi * a ** 2, rtol=3e-3)
    assert np.all(tank.distance_to_boundary_m(np.array([e.centre_m for e in scene.electrodes]))[:, 0] < 1e-12)


def test_electrode_heights_found_and_the_rest_split_on_a_synthetic_phantom(tmp_path):
    """Ring electrodes a few mm off their stated height (random, unseen by the scene file): the diagnosis names an
    electrode-position candidate, finds the heights, and leaves a remainder at the noise, which breaks reciprocity."""
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.comparison.transfer import compare_transfer_log
    from electrosense.validation.diagnosis.transfer import diagnose_transfer

    rng = np.random.default_rng(5)
    dz = rng.uniform(-1, 1, 8)
    dz = 0.004 * (dz - dz.mean()) / np.abs(dz - dz.mean()).max()      # up to 4 mm, the ring's mean height kept
    mat = _synthetic_phantom(tmp_path, rng, dz_m=dz, noise=2e-4)
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="tank.toml"))
    scene, settings = load_scene(tmp_path / "tank.toml"), load_scene_settings(tmp_path / "tank.toml")
    comp = compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"])
    d, _, _, _ = diagnose_transfer(comp, scene, 1.0, settings["bem"], settings["protocol"])
    assert d["chosen"] == "electrode_heights" and d["verdict"] == "explained", d["engine"]["steps"]
    assert d["shrink"] > 0.8
    # the engine's answer: the heights made exact on the BEM where they were fitted (Newton steps on its solves)
    assert len(d["engine"]["bem_secants"][0]["solves"]) >= 2
    found = np.array(list(d["engine"]["parameters"]["electrode_heights"].values()))
    assert np.abs(found - found.mean() - dz).max() < 0.25 * np.abs(dz).max()
    se = np.array(list(d["engine"]["standard_errors"]["electrode_heights"].values()))      # the noise's share
    assert np.all(np.abs(found - found.mean() - dz) < 4 * se + 2e-4)
    # the table lists it beside the linear candidates, in mm
    found = np.array(d["candidates"]["electrode_heights, made exact on the BEM"]["height_offsets_mm"]) * 1e-3
    assert np.abs(found - found.mean() - dz).max() < 0.25 * np.abs(dz).max()
    shares = d["remaining"]["shares"]
    assert abs(sum(shares.values()) - 1) < 1e-9


def test_where_the_rest_lies_calls_independent_noise_noise_and_a_reciprocal_pattern_shared():
    """Independent errors on every measurement (16-electrode adjacent protocol): the split names them noise, not
    scatter shared by reciprocal pairs; a reciprocal pattern on top of them (a gain per pair, driving and measuring
    alike) is found shared."""
    from electrosense.validation.comparison.transfer import ring_offsets
    from electrosense.validation.diagnosis.transfer_remainder import where_the_rest_lies

    rng = np.random.default_rng(4)
    ring = list(range(1, 17))
    d, m = adjacent_protocol(ring)
    keep = ~involves_drive(d, m)
    drive = np.repeat(d, len(m), axis=0)[keep.ravel()]
    meas = np.tile(m, (len(d), 1))[keep.ravel()]
    off = ring_offsets(drive, meas, ring)
    noise = 0.01 * rng.standard_normal(len(drive))
    split = where_the_rest_lies(drive, meas, off, noise, ring=ring)
    assert split["shares"]["noise"] > 0.75 and split["shares"]["shared_by_reciprocal_pairs"] < 0.2
    g = 0.03 * rng.standard_normal(len(ring))
    pattern = g[drive[:, 0] - 1] + g[meas[:, 0] - 1]       # a pair (k, k+1) by its first electrode
    split = where_the_rest_lies(drive, meas, off, noise + pattern, ring=ring)
    assert split["shares"]["shared_by_reciprocal_pairs"] > 0.6


@pytest.mark.parametrize("module", ["electrosense.validation.comparison.transfer",
                                    "electrosense.validation.comparison.transfer_report",
                                    "electrosense.validation.diagnosis.transfer",
                                    "electrosense.validation.diagnosis.transfer_remainder"])
def test_transfer_modules_examples_run(module):
    import doctest
    import importlib

    result = doctest.testmod(importlib.import_module(module))
    assert result.attempted > 0 and result.failed == 0


def test_a_fitted_move_off_the_wall_is_shortened_and_said(tmp_path):
    """A linear fit that puts an electrode 1.3 m up the wall (out of the water, as one did on a real file): the BEM
    step at the fitted scene halves the move until every disc is on the wall, says so, and solves; a move of which
    no half fits (onto the neighbour and beyond the floor at once) is refused without a solve."""
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.comparison.transfer import compare_transfer_log
    from electrosense.validation.diagnosis.transfer import solver_at, step_on_the_wall, wall_discs

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(2), noise=2e-4)
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="tank.toml"))
    scene, settings = load_scene(tmp_path / "tank.toml"), load_scene_settings(tmp_path / "tank.toml")
    comp = compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"])
    wall = [w for w in wall_discs(scene) if w.index + 1 in settings["protocol"]["ring"]]
    up = np.zeros(len(wall))
    up[0] = 1.3
    solve_at = solver_at(scene, wall, None, 1.0, settings["bem"], comp)
    Z, fraction, note, columns = solve_at("electrode_heights", up)
    assert Z.shape == comp.Z_model_ohm.shape and columns.shape == (len(Z), len(wall)) and "shortened to" in note
    assert "is not on the tank's boundary" in note
    assert abs(fraction * up[0]) < scene.tank.water_depth_m
    f, why = step_on_the_wall(scene, wall, np.zeros(len(wall)), np.zeros(len(wall)),
                              np.r_[1e3, np.zeros(len(wall) - 1)], np.r_[-1e3, np.zeros(len(wall) - 1)])
    assert f == 0 and why
    spacing = 2 * np.pi * scene.tank.radius_at(wall[0].centre_m[2]) / len(wall)
    f, why = step_on_the_wall(scene, wall, np.zeros(len(wall)), np.zeros(len(wall)),
                              np.r_[1.6 * spacing, np.zeros(len(wall) - 1)], np.zeros(len(wall)))
    assert f == 0.5 and ("pass each other" in why or "overlap" in why)     # past its neighbour: half of it stays


def test_a_multiplexer_group_gain_is_found_on_held_out_set_ups(tmp_path):
    """The odd-odd class of (drive pair, measurement pair) read 9 % low, in every set-up (an instrument's group):
    drives held out by parity cannot see it (the even drives never meet the odd classes), set-ups held out can.
    Fitted on the empty tank, ``pair_parity_gains`` predicts the ball set-up to the noise and finds the 0.91."""
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.comparison.transfer import compare_transfer_log
    from electrosense.validation.diagnosis.transfer import diagnose_transfer

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(8), noise=2e-4)
    d = scipy.io.loadmat(mat)
    n = 8
    k, m = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")      # drive k: pair (k+1, k+2); measurement m
    gain = np.where((k % 2 == 1) & (m % 2 == 1), 0.91, 1.0)
    for s in ("Ref", "Avg1"):
        d["vv" + s] = (d["vv" + s].reshape(n, n) * gain).reshape(-1, 1)
    scipy.io.savemat(mat, {k: v for k, v in d.items() if not k.startswith("__")})
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="tank.toml"))
    scene, settings = load_scene(tmp_path / "tank.toml"), load_scene_settings(tmp_path / "tank.toml")
    comp = compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"])
    diag, _, _, _ = diagnose_transfer(comp, scene, 1.0, settings["bem"], settings["protocol"])
    cand = diag["candidates"]["pair_parity_gains"]
    stated = diag["stated_geometry_heldout_setups"]["empty_to_objects_rms_rel"]
    assert stated > 0.02                                             # the groups' 9 % shows on the ball set-up
    assert cand["heldout_setups"]["empty_to_objects_rms_rel"] < 0.1 * stated
    assert cand["heldout_setups"]["Avg1"] == cand["heldout_setups"]["empty_to_objects_rms_rel"]
    parity_gap = comp.metrics["empty_heldout_rms_rel"]                 # odd drives held out, fitted on the even
    assert abs(cand["heldout_rms_rel"] - parity_gap) < 0.2 * parity_gap    # drives held out by parity cannot tell
    # the engine holds out every fifth drive (both parities in each fold): it sees the classes and names them
    assert diag["chosen"] == "pair_parity_gains" and diag["verdict"] == "explained", diag["engine"]["steps"]
    gains = diag["engine"]["parameters"]["pair_parity_gains"]
    assert abs(gains["gain_odd-odd"] + 0.09) < 0.01 and abs(gains["gain_even-odd"]) < 0.01
    found = cand["heldout_setups"]["fitted_on_the_empty_tank"]["pair_parity_gains_rel"]
    assert abs(found["odd-odd"] - 0.91) < 0.01 and abs(found["even-odd"] - 1) < 0.01


def test_a_ball_on_a_symmetry_of_the_tank_gives_each_row_and_its_images_one_signal_and_what_breaks_it_is_the_floor():
    """The BEM's signal of a ball on the axis of a round tank with an even ring, or on a mirror plane of it, is the
    same on every row's images under the scene's symmetries (its symmetric floor is the mesh's own asymmetry,
    every scene on one tank mesh); a drive pattern whose signal is 40 % off raises the floor to what no scene
    with that symmetry can fit, and anything the symmetry allows added changes nothing."""
    from dataclasses import replace

    from electrosense.meshes.objects import Sphere
    from electrosense.meshes.scene_mesh import objects_focus_m
    from electrosense.validation.comparison.symmetry import scene_symmetries, symmetric_floor
    from electrosense.validation.comparison.transfer import solved_transfer_ohm

    rng = np.random.default_rng(5)
    n, R, H = 8, rng.uniform(0.08, 0.12), rng.uniform(0.1, 0.14)
    z, phi0 = -0.1 * H, rng.uniform(0, 2 * np.pi)
    scene = Scene(None, tank=CylinderTank(R, H), electrodes=[
        DiscElectrode((R * np.cos(phi0 + 2 * np.pi * k / n), R * np.sin(phi0 + 2 * np.pi * k / n), z), 0.006)
        for k in range(n)] + [DiscElectrode((0.0, 0.0, -0.5 * H), 0.005)] + [    # a second ring, not measured
        DiscElectrode((R * np.cos(phi0 + 2 * np.pi * k / n), R * np.sin(phi0 + 2 * np.pi * k / n), 0.3 * H), 0.006)
        for k in range(n)])
    d, m = adjacent_protocol(range(1, n + 1))
    keep = ~involves_drive(d, m)
    drive, measure = np.repeat(d, n, axis=0)[keep.ravel()], np.tile(m, (n, 1))[keep.ravel()]
    on_mirror = 0.3 * R * np.array([np.cos(phi0 + np.pi / n), np.sin(phi0 + np.pi / n)])  # between 1 and 2
    assert len(scene_symmetries(scene, [[0.0, 0.0]])) == 2 * n
    assert len(scene_symmetries(scene, [on_mirror])) == 2
    assert len(scene_symmetries(scene, [on_mirror + 0.01])) == 1
    for xy in ([0.0, 0.0], on_mirror):
        ball = Sphere((*xy, z), radius_m=0.3 * R)
        options = {"tank_edge_length_m": R / 2, "edge_fraction": 0.5, "electrode_grading": 1.0,
                   "tank_focus_m": objects_focus_m([ball])}       # one tank mesh for both scenes
        empty = solved_transfer_ohm(scene, 1.0, options, drive, measure)
        signal = solved_transfer_ohm(replace(scene, objects=(ball,)), 1.0, options, drive, measure) / empty - 1
        maps = scene_symmetries(scene, [xy])
        assert symmetric_floor(drive, measure, signal, maps) < 0.02
        odd = signal * np.where(drive[:, 0] == 3, 1.4, 1.0)
        floor = symmetric_floor(drive, measure, odd, maps)
        assert floor > 0.05
        rows = [(frozenset(a), frozenset(b)) for a, b in zip(drive.tolist(), measure.tolist())]
        where = {r: i for i, r in enumerate(rows)}
        v = rng.normal(0, np.std(signal), len(rows))          # a pattern the symmetry allows: v averaged over it
        allowed = np.array([np.mean([v[where[(frozenset(g[e] for e in a), frozenset(g[e] for e in b))]]
                                     for g in maps]) for a, b in rows])
        rms = lambda x: np.sqrt(np.mean(x**2))                 # noqa: E731
        assert symmetric_floor(drive, measure, odd + allowed, maps) * rms(odd + allowed) == pytest.approx(
            floor * rms(odd))


def _crosstalk_phantom(tmp_path, seed, shares, rename_reference=False):
    """The synthetic phantom with a fixed reading added per class of (drive, measurement) by their parity (even-even,
    even-odd, odd-even, odd-odd: ``shares`` of the median reading) in both set-ups, compared with its scene.
    Returns the comparison, the scene, its settings and the offsets (V)."""
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.comparison.transfer import compare_transfer_log

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(seed), noise=2e-4)
    d = {k: v for k, v in scipy.io.loadmat(mat).items() if not k.startswith("__")}
    if rename_reference:
        d["voltRef"] = d.pop("voltsRef")
    n = 8
    k, m = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")      # drive k: pair (k+1, k+2); measurement m
    offset = np.asarray(shares) * np.median(np.abs(d["vvRef"][d["vvRef"] != 0]))
    for s in ("Ref", "Avg1"):
        vv = d["vv" + s].reshape(n, n)
        d["vv" + s] = np.where(vv != 0, vv + offset[2 * (k % 2) + m % 2], 0.0).reshape(-1, 1)
    scipy.io.savemat(mat, d)
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="tank.toml"))
    scene, settings = load_scene(tmp_path / "tank.toml"), load_scene_settings(tmp_path / "tank.toml")
    return compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"]), scene, settings, offset


def test_a_multiplexer_group_crosstalk_is_named_on_a_file_that_names_its_arrays_otherwise(tmp_path):
    """A fixed voltage added per class of (drive pair, measurement pair) in every set-up (a multiplexer group's
    crosstalk: relative to the reading, largest on the far side and alternating there with the ring offset's
    parity), in a file whose reference array is named ``voltRef``: read, the offsets named by the engine with
    each class's value within four standard errors, the gap brought to the noise."""
    from electrosense.validation.diagnosis.transfer import diagnose_transfer

    # even-even, even-odd, odd-even, odd-odd; the two mixed classes alike, so reciprocity holds
    comp, scene, settings, offset = _crosstalk_phantom(tmp_path, 5, (0.0, 0.03, 0.03, -0.02), rename_reference=True)
    diag, _, _, _ = diagnose_transfer(comp, scene, 1.0, settings["bem"], settings["protocol"])
    assert diag["gap_before"] > 10 * diag["gap_after"], diag["engine"]["steps"]
    assert diag["chosen"] == "pair_parity_offsets" and diag["verdict"] == "explained", diag["engine"]["steps"]
    found = diag["engine"]["parameters"]["pair_parity_offsets"]
    se = diag["engine"]["standard_errors"]["pair_parity_offsets"]
    assert comp.metrics["noise_floor"]["per_measurement_rms_rel"] < 0.01
    true_ohm = offset / 4.6e-3 / np.median(comp.Z_measured_ohm / np.abs(comp.Z_model_ohm))   # 4.6 mA: the file's
    assert np.all(np.abs(np.array(list(found.values())) - true_ohm) < 4 * np.array(list(se.values())))
    assert max(se.values()) < 0.1 * np.max(np.abs(true_ohm))


def test_a_protocol_without_the_balls_height_takes_the_rings_plane_and_says_so(tmp_path):
    """The scene's [protocol] gives the balls' radius but not their height: the comparison (and the scene fit) take
    the ring's plane, where the data's ball is, and the metrics say what was taken."""
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.comparison.transfer import compare_transfer_log
    from electrosense.validation.diagnosis.tank_scene_fit import ring_state

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(6), noise=2e-4)
    log = read_transfer_log(eit_mat_to_transfer_log(mat, tmp_path / "log.csv", scene="tank.toml"))
    scene, settings = load_scene(tmp_path / "tank.toml"), load_scene_settings(tmp_path / "tank.toml")
    stated = compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"])
    z_ring = settings["protocol"].pop("ball_z_m")                  # the synthetic phantom's ball: in the ring's plane
    comp = compare_transfer_log(log, scene, 1.0, settings["bem"], settings["protocol"])
    assert comp.metrics["ball_height"]["assumed_z_m"] == pytest.approx(z_ring)
    assert "the ring's plane" in comp.metrics["ball_height"]["not_stated"][0]
    assert not stated.metrics["ball_height"]["not_stated"]
    assert comp.metrics["object_rms_rel"]["Avg1"] == pytest.approx(stated.metrics["object_rms_rel"]["Avg1"])
    assert ring_state(scene, settings["protocol"])["ball_z_m"] == pytest.approx(z_ring)


def test_a_scene_without_a_bem_table_is_solved_on_the_coarsest_mesh_the_noise_hides(tmp_path):
    """No [bem] table: the study climbs the mesh ladder and takes the first level whose estimated error is within
    half the data's noise, and the report says so; a stated table is used as written, and without a noise floor
    the solver's defaults are taken, neither with a solve."""
    import re

    from electrosense.meshes.scene_file import load_scene
    from electrosense.validation.cli.transfer_logs import run_transfer_comparison
    from electrosense.validation.comparison.study_mesh import BEM_ERROR_OVER_NOISE, mesh_level, study_bem_options

    mat = _synthetic_phantom(tmp_path, np.random.default_rng(11), noise=0.02)
    toml = tmp_path / "tank.toml"
    toml.write_text(re.sub(r"\[bem\][^\[]*", "", toml.read_text()))
    scene = load_scene(toml)

    def no_solve(K):
        raise AssertionError("no solve expected")

    stated = {"tank_edge_length_m": 0.05}
    assert study_bem_options(scene, 1.0, stated, no_solve, 0.02)[0] == stated
    options, record, solution = study_bem_options(scene, 1.0, {}, no_solve, float("nan"))
    assert record["chosen"] == "defaults" and options == mesh_level(scene.tank, 3) and not record.get("levels")
    assert solution is None
    # the study: the data's own floor picks the mesh
    metrics = run_transfer_comparison(mat, toml, tmp_path / "out", diagnose=False)
    mesh = metrics["bem"]["mesh"]
    noise = metrics["noise_floor"]["fit_noise_rel"]
    assert mesh["threshold_rel"] == pytest.approx(BEM_ERROR_OVER_NOISE * noise)
    k = mesh["chosen"]
    assert k in (0, 1, 2) and 0 < mesh["levels"][k]["error_rms_rel"] <= mesh["threshold_rel"]
    assert all(lv["error_rms_rel"] > mesh["threshold_rel"] for lv in mesh["levels"][:k])
    assert mesh["options"] == mesh_level(scene.tank, k) and metrics["bem"]["triangles"] == mesh["levels"][k]["triangles"]
    triangles = [lv["triangles"] for lv in mesh["levels"]]
    assert triangles == sorted(triangles) and len(set(triangles)) == len(triangles)
    assert "no [bem] table: mesh level" in (tmp_path / "out" / "report.md").read_text()


def test_a_crosstalk_that_breaks_reciprocity_is_taken_out_of_the_noise_and_named(tmp_path):
    """The mixed multiplexer classes' crosstalks differ (even-odd 5 %, odd-even 1 % of the median reading): the
    reciprocity floor holds that difference, measured and taken out of the noise the engine assumes (it was the
    floor, and the engine called the rest explained at once); the engine still names the crosstalk."""
    from electrosense.validation.diagnosis.transfer import diagnose_transfer

    comp, scene, settings, offset = _crosstalk_phantom(tmp_path, 7, (0.0, 0.05, 0.01, -0.02))
    noise = comp.metrics["noise_floor"]
    assert noise["parity_offsets"]["p_value"] < 1e-6
    true_difference_ohm = (offset[1] - offset[2]) / 4.6e-3                # the file's 4.6 mA
    assert abs(noise["parity_offsets"]["difference_ohm"] - true_difference_ohm) < max(
        4 * noise["parity_offsets"]["standard_error_ohm"], 0.02 * true_difference_ohm)
    assert noise["fit_noise_rel"] < noise["per_measurement_rms_rel"] / 5
    diag, _, _, _ = diagnose_transfer(comp, scene, 1.0, settings["bem"], settings["protocol"])
    assert diag["noise_rel"] == noise["fit_noise_rel"] and "crosstalk" in diag["noise_from"]
    assert diag["chosen"] == "pair_parity_offsets" and diag["verdict"] == "explained", diag["engine"]["steps"]
    assert diag["gap_before"] > 10 * diag["gap_after"]
