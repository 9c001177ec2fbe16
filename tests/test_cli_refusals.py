"""Refusals instead of tracebacks, hangs or wrong answers: each names the option the user typed."""
import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.validation.cli import main


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.parametrize("rate", ["inf", "nan", "0", "-2"])
def test_bench_sim_rate_must_be_finite_and_positive(tmp_path, rate):
    r = _run("bench-sim", "-o", tmp_path / "r.csv", "--rate", rate)
    assert r.exit_code != 0 and "--rate" in r.output and not (tmp_path / "r.csv").exists()


def test_bench_sim_truth_with_output_is_refused_not_ignored(tmp_path):
    r = _run("bench-sim", "-o", tmp_path / "r.csv", "--truth", tmp_path / "t.csv")
    assert r.exit_code != 0 and "--truth" in r.output and not (tmp_path / "r.csv").exists()


def test_an_edge_length_making_millions_of_triangles_is_refused_at_once(tmp_path):
    import time

    t0 = time.perf_counter()
    for cmd in (("conductance", "--sensor", "angels-4"), ("mesh", "sensor", "angels-4", "-o", tmp_path / "m.vtp")):
        r = _run(*cmd, "--edge-length", "0.00005")
        assert r.exit_code != 0 and "--edge-length" in r.output and "triangles" in r.output, r.output
    assert time.perf_counter() - t0 < 20


def test_sigma_is_named_as_typed():
    r = _run("conductance", "--sensor", "angels-2", "--sigma", "-1")
    assert r.exit_code != 0 and "--sigma" in r.output and "sigma_S_per_m" not in r.output


def test_pose_without_a_tank_is_explained():
    r = _run("conductance", "--sensor", "angels-2", "--pose", "0.1,0,0,0")
    assert r.exit_code != 0 and "--pose" in r.output and "--tank" in r.output


def test_conductance_default_sigma_is_the_nominal_one():
    from electrosense.validation.cli.conductance_cmd import conductance
    from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M

    sigma = next(p for p in conductance.params if p.name == "sigma")
    assert str(NOMINAL_SIGMA_S_PER_M) in sigma.help


def test_a_mesh_whose_shells_intersect_is_refused(tmp_path):
    import trimesh

    from electrosense.meshes.io import write_mesh
    from electrosense.meshes.labelled_mesh import LabelledMesh

    rng = np.random.default_rng(3)
    r = rng.uniform(0.005, 0.02)
    a = trimesh.creation.icosphere(2, r)
    b = trimesh.creation.icosphere(2, r).apply_translation([rng.uniform(0.5, 1.5) * r, 0, 0])
    both = trimesh.util.concatenate([a, b])
    labels = np.concatenate([np.ones(len(a.faces), int), np.full(len(b.faces), 2)])
    write_mesh(LabelledMesh(both.vertices, both.faces, labels), tmp_path / "bad.vtp")
    res = _run("conductance", "--mesh", tmp_path / "bad.vtp")
    assert res.exit_code != 0 and "--mesh" in res.output and "intersect" in res.output


@pytest.mark.parametrize("args, option", [
    (("--tank", "1,1"), "--tank"),
    (("--tank", "none", "--depth", "0.5"), "--depth"),
    (("--tank", "none", "--tank-grading", "0.15"), "--tank-grading"),
    (("--tank-grading", "0"), "--tank-grading"),
    (("--depth", "2"), "--depth"),
    (("--emitter", "9"), "--emitter"),
    (("--sigma", "nan"), "--sigma"),
])
def test_bench_sim_names_the_option(tmp_path, args, option):
    r = _run("bench-sim", "-o", tmp_path / "r.csv", "--path", "wall-to-wall:5", *args)
    assert r.exit_code != 0 and option in r.output and not (tmp_path / "r.csv").exists(), r.output


def test_a_study_that_needs_an_extra_is_refused_before_any_work(tmp_path, monkeypatch):
    """`esense study tank_map` runs `esense sweep` for its speed check: on a base install (no dask, zarr) it used to
    build its map and check it for nine minutes, then end in an internal error with its figures lost."""
    import importlib.util

    import electrosense.validation.studies.tank_map as study

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "zarr" else real(name, *a))
    monkeypatch.setattr(study, "main", lambda argv=None: pytest.fail("the study started"))
    for cmd in (("study", "tank_map", "-o", tmp_path / "s"), ("sweep", "--model", "psm", "--sensor", "angels-2",
                                                              "--from", "0,0", "--to", "0.1,0", "--steps", 2,
                                                              "-o", tmp_path / "s.csv")):
        r = _run(*cmd)
        assert r.exit_code != 0 and "needs zarr: pip install 'electrosense[sweep]'" in r.output, r.output
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("z", ["nan", "0:inf", "-0.1:0.1:0.2", "0.1:-0.1"])
def test_map_build_names_a_bad_height(tmp_path, z):
    """A height that is no finite number, or a band upside down, is refused naming ``--z`` before any work."""
    res = CliRunner().invoke(main, ["map", "build", "--sensor", "angels-4", "--tank", "0.6,0.5,0.4", "--z", z,
                                    "-o", str(tmp_path / "m.npz")])
    assert res.exit_code == 2 and "--z" in res.output and not list(tmp_path.iterdir()), res.output
