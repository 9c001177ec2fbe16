"""`esense validate` end to end on logs made by the PSM (fast: no BEM)."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.meshes.tank import Tank
from electrosense.psm import PolySphericalModel, conductance
from electrosense.validation.bench.log import write_bench_log
from electrosense.validation.cli.validate_cmd import validate
from electrosense.validation.report.figures import png_is_blank

SIGMA = 0.0354


@pytest.fixture(scope="module")
def psm_file(tmp_path_factory):
    """A 4-sphere PSM of the paper's fitted size (a_e = 0.72 cm, a_i = 0.74 cm, L = 7.85 / 7.69 cm)."""
    model = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])
    path = tmp_path_factory.mktemp("psm") / "electrosense.psm.json"
    model.save(path)
    return path, model


def _log(path, model, scale=1.0, n=25):
    x = np.linspace(-0.36, 0.36, n)
    poses = np.column_stack([x, np.zeros(n), np.zeros(n), np.zeros(n)])
    C = conductance(model, poses, SIGMA, tank=Tank((1.0, 1.0, 1.0)))
    I = scale * C.receiver_currents_A(np.ones(n))
    data = {"t_s": np.arange(n) * 0.1, "x_m": x, "y_m": 0 * x, "z_m": 0 * x, "yaw_rad": 0 * x, "U_V": np.ones(n)}
    data.update({f"I{k}_A": I[:, j] for j, k in enumerate(C.receivers)})
    meta = {"sensor": "angels-4", "emitter": 4, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": SIGMA}
    write_bench_log(path, meta, data)
    return path


def test_validate_psm_log_zero_error_and_known_scale(tmp_path, psm_file):
    psm_path, model = psm_file
    exact = _log(tmp_path / "exact.csv", model)
    scaled = _log(tmp_path / "scaled.csv", model, scale=0.98)
    out = tmp_path / "report"
    result = CliRunner().invoke(validate, [str(exact), str(scaled), "--models", "psm", "--psm", str(psm_path),
                                           "--conductivity-correction", "-o", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    logs = {d["log"]: d for d in metrics["logs"]}
    assert logs["exact"]["models"]["psm"]["vs_bench"]["all"]["max_abs"] < 1e-12
    scaled_psm = logs["scaled"]["models"]["psm"]
    assert scaled_psm["vs_bench"]["all"]["bias"] == pytest.approx(1 / 0.98 - 1, rel=1e-9)
    assert scaled_psm["conductivity_correction"]["scale"] == pytest.approx(0.98, rel=1e-12)
    assert scaled_psm["vs_bench_corrected"]["all"]["max_abs"] < 1e-12
    # regions of the wall-to-wall path: both walls and the middle
    assert {"mid-tank", "near wall_x-", "near wall_x+"} <= set(logs["exact"]["region_counts"])
    html = (out / "index.html").read_text()
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) >= 8  # resistance, error, regions, scene for each log
    for png in pngs:
        assert png.name in html
        assert not png_is_blank(png)
    assert "report:" in result.output and "-2.00 %" in result.output


def test_validate_refuses_bad_input(tmp_path, psm_file):
    psm_path, model = psm_file
    log = _log(tmp_path / "a.csv", model, n=5)
    r = CliRunner().invoke(validate, [str(log), "--models", "fem", "-o", str(tmp_path / "o")])
    assert r.exit_code != 0 and "--models" in r.output
    bad = tmp_path / "bad.csv"
    bad.write_text("# esense-bench-log 2\n")
    r = CliRunner().invoke(validate, [str(bad), "--models", "psm", "-o", str(tmp_path / "o")])
    assert r.exit_code != 0 and "bad.csv" in r.output
