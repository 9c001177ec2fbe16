"""`esense diagnose` end to end on bench-log files."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.validation.cli import main
from electrosense.validation.diagnosis.blind import BlindSetup, assemble, blind_poses, world_currents, write_log
from electrosense.validation.diagnosis.forward import PSMEffectModel


@pytest.fixture(scope="module")
def psm_world():
    from electrosense.validation.simulation.models import calibrated_psm

    setup = BlindSetup()  # the world: the same calibrated PSM as the command's baseline (--model psm)
    return setup, PSMEffectModel(setup.sensor, setup.sigma_S_per_m, calibrated_psm(setup.sensor))


def _log(tmp_path, psm_world, name, seed, **output):
    setup, world = psm_world
    poses, t, passes = blind_poses(30)
    obs = assemble(setup, poses, t, passes, world_currents(world, setup, poses, None), np.random.default_rng(seed),
                   **output)
    return write_log(obs, tmp_path / name)


def test_diagnose_writes_json_and_page(tmp_path, psm_world):
    log = _log(tmp_path, psm_world, "run.csv", 1, conductivity=-0.02)
    out = tmp_path / "diag"
    res = CliRunner().invoke(main, ["diagnose", str(log), "--model", "psm", "-o", str(out)])
    assert res.exit_code == 0, res.output
    d = json.loads((out / "diagnosis.json").read_text())
    for key in ("gap_before", "gap_after", "where", "ranking", "chosen", "confusable"):
        assert key in d
    assert d["chosen"][0] == "conductivity"
    assert d["gap_after"] < 0.2 * d["gap_before"]
    assert d["where"]["concentration"]["share"] > 0
    first = d["ranking"][0]
    assert set(first) >= {"effect", "params", "uncertainty", "heldout_gap", "shrink"}
    assert first["params"]["sigma_rel_change"] == pytest.approx(-0.02, abs=1e-3)
    assert (out / "index.html").exists() and "Sim-to-real gap diagnosis" in (out / "index.html").read_text()


def test_two_logs_and_an_effect_subset(tmp_path, psm_world):
    a = _log(tmp_path, psm_world, "a.csv", 2)
    b = _log(tmp_path, psm_world, "b.csv", 3)
    out = tmp_path / "d2"
    res = CliRunner().invoke(main, ["diagnose", str(a), str(b), "--model", "psm", "--effects", "conductivity,channel_gain",
                                    "--no-figures", "-o", str(out)])
    assert res.exit_code == 0, res.output
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["chosen"] == ["none"]
    assert {r["effect"] for r in d["ranking"]} == {"conductivity", "channel_gain", "none"}
    assert d["n_passes"] == 4


def test_unknown_effect_is_refused(tmp_path, psm_world):
    log = _log(tmp_path, psm_world, "c.csv", 4)
    res = CliRunner().invoke(main, ["diagnose", str(log), "--model", "psm", "--effects", "gremlins", "-o", str(tmp_path / "x")])
    assert res.exit_code != 0 and "gremlins" in res.output
