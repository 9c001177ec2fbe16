"""The tank map: exact at its BEM poses, its estimated error honest off them, one file, resumable, and a sweep model.

A small tank and coarse meshes keep it quick; the accuracy over a real tank is the study's (README, issue 23).
"""
import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.meshes import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.simulation.models import pose_evaluator
from electrosense.validation.simulation.tank_map import build_tank_map, load_tank_map, reachable_poses

SENSOR = preset("angels-2")
TANK = Tank((0.4, 0.3, 0.2))
OPTIONS = {"tank_edge_length_m": 0.04}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    path = tmp_path_factory.mktemp("map") / "m.npz"
    m = build_tank_map(SENSOR, TANK, 0.0, path=path, wall_gap_m=0.02, spacing_m=0.04, n_headings=8, first=10,
                       per_round=5, max_seconds=5, bem_options=OPTIONS,
                       workers=1)
    return m, path


def test_the_map_is_the_bem_at_its_nodes_and_survives_its_file(built):
    m, path = built
    iu = np.triu_indices(SENSOR.n_electrodes, 1)   # the map keeps the BEM's upper triangle, symmetric
    assert np.allclose(m.conductance(m.nodes)[:, iu[0], iu[1]], m.K_nodes[:, iu[0], iu[1]], rtol=1e-8, atol=0)
    again = load_tank_map(path)
    P = reachable_poses(SENSOR, TANK, 0.0, 0.02, 0.013, 8)[::7]
    assert np.allclose(again.conductance(P, 0.05), m.conductance(P, 0.05), rtol=1e-12)
    K = m.conductance(P)
    assert np.allclose(K.sum(axis=-1), 0, atol=1e-12 * np.abs(K).max())
    J = m.jacobian(P[:3])
    assert J.shape == (3, 3) + K.shape[1:]


def test_a_build_resumes_from_its_file(built):
    m, path = built
    more = build_tank_map(SENSOR, TANK, 0.0, path=path, wall_gap_m=0.02, spacing_m=0.04, n_headings=8, first=10,
                          per_round=3, max_seconds=0, bem_options=OPTIONS,
                          workers=1)
    assert np.array_equal(more.nodes[:len(m.nodes)], m.nodes)   # nothing solved twice
    assert len(more.nodes) >= len(m.nodes)


def test_the_estimated_error_is_the_size_of_the_true_one(built):
    m, _ = built
    from electrosense.validation.diagnosis.anchored import default_bem_options

    rng = np.random.default_rng(0)
    P = reachable_poses(SENSOR, TANK, 0.0, 0.02, 0.013, 8)
    P = P[rng.choice(len(P), 5, replace=False)]
    bem = pose_evaluator("bem", SENSOR, TANK, 1.0, (), poses=m.nodes, **default_bem_options(SENSOR, OPTIONS))
    e = SENSOR.emitter - 1
    r = [k for k in range(SENSOR.n_electrodes) if k != e]
    true = np.abs(m.conductance(P)[:, r, e] / bem.conductance(P).K_S[:, r, e] - 1).max(axis=1)
    est = m.estimated_error(P).max(axis=1)
    assert np.sqrt(np.mean(true**2)) < 3 * np.sqrt(np.mean(est**2)) + 1e-3   # another tank mesh adds ~5e-4


def test_the_map_refuses_what_it_does_not_cover(built):
    m, _ = built
    ev = pose_evaluator("map", SENSOR, TANK, 0.05, tank_map=m)
    with pytest.raises(ValueError, match="z = "):
        ev.conductance(np.array([[0.0, 0.0, 0.01, 0.0]]))
    with pytest.raises(ValueError, match="from a wall"):
        ev.conductance(np.array([[0.135, 0.0, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="map is of"):
        pose_evaluator("map", preset("angels-4"), TANK, 0.05, tank_map=m)


def test_sweep_with_the_map(built, tmp_path):
    from electrosense.validation.cli import main

    _, path = built
    out = tmp_path / "line.csv"
    res = CliRunner().invoke(main, ["sweep", "--model", "map", "--map", str(path), "--from", "-0.05,0", "--to",
                                    "0.05,0", "--steps", "5", "-o", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    assert out.exists()
