"""Calibration on the paper's criterion (17): the paper's table, round trips, refusals."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.bem.conductance import ConductanceMatrix, K_from_S
from electrosense.psm import CalibrationError, PolySphericalModel, calibrate, conductance
from electrosense.psm.paper import FIT_N4, RADIUS_N2_M, paper_reference

SIGMA = 0.0354


def test_symmetric_fit_of_the_paper_table_lands_on_the_paper_parameters():
    cal = calibrate(paper_reference(), symmetric=True)
    a_e, a_i, L_e, L_i = cal.parameters
    assert abs(a_e - FIT_N4["a_e"]) < 0.02e-2
    assert abs(a_i - FIT_N4["a_i"]) < 0.02e-2
    assert abs(L_e - FIT_N4["L_e"]) < 0.05e-2
    assert abs(L_i - FIT_N4["L_i"]) < 0.05e-2
    assert cal.gamma_criterion < 1e-3
    assert cal.parameter_names == ("a_1=a_4", "a_2=a_3", "L_12=L_34", "L_23")
    assert np.all(cal.uncertainties > 0)
    np.testing.assert_allclose(np.diag(cal.correlations), 1.0)
    S = conductance(cal.model, np.zeros((1, 4)), SIGMA).S_S[0]
    assert np.sqrt(np.trace((S - paper_reference().S_S) @ (S - paper_reference().S_S))
                   / np.trace(paper_reference().S_S @ paper_reference().S_S)) == pytest.approx(cal.gamma_criterion, rel=1e-9)


def test_two_electrodes_with_fixed_length_recover_the_equal_radius():
    truth = PolySphericalModel.collinear([RADIUS_N2_M] * 2, [0.2])
    ref = conductance(truth, np.zeros((1, 4)), SIGMA)[0]
    cal = calibrate(ref, symmetric=True, fix_length_m=0.2)
    assert cal.parameter_names == ("a_1=a_2",)
    assert cal.parameters[0] == pytest.approx(RADIUS_N2_M, rel=1e-9)
    assert cal.model.length_m == pytest.approx(0.2)


def test_symmetric_four_sphere_round_trip():
    truth = PolySphericalModel.collinear([0.008, 0.006, 0.006, 0.008], [0.07, 0.09, 0.07])
    cal = calibrate(conductance(truth, np.zeros((1, 4)), SIGMA)[0], symmetric=True)
    np.testing.assert_allclose(cal.parameters, [0.008, 0.006, 0.07, 0.09], rtol=1e-7)
    assert cal.gamma_criterion < 1e-9


def test_refuses_non_symmetric_non_definite_and_underdetermined_references():
    S = paper_reference().S_S.copy()
    bad = S.copy()
    bad[0, 1] *= 1.3
    K = K_from_S(S, 4)
    K[0, 1] *= 1.3
    with pytest.raises(CalibrationError, match="not symmetric"):
        calibrate(ConductanceMatrix(K, 4, SIGMA), symmetric=True)
    with pytest.raises(CalibrationError, match="not positive definite"):
        calibrate(ConductanceMatrix(K_from_S(-S, 4), 4, SIGMA), symmetric=True)
    with pytest.raises(CalibrationError, match="7 parameters"):
        calibrate(paper_reference(), symmetric=False)


def test_calibrated_model_json_round_trip(tmp_path):
    cal = calibrate(paper_reference(), symmetric=True)
    cal.model.save(tmp_path / "electrosense.psm.json")
    back = PolySphericalModel.load(tmp_path / "electrosense.psm.json")
    np.testing.assert_array_equal(back.radii_m, cal.model.radii_m)
    assert back.gamma_criterion == cal.gamma_criterion
    again = ConductanceMatrix.from_json_dict(back.reference)
    np.testing.assert_array_equal(again.K_S, paper_reference().K_S)
    assert again.emitter == 4


def test_cli_calibrate_paper_table_and_reference_file(tmp_path):
    from electrosense.validation.cli.calibrate_cmd import calibrate as cmd

    out = tmp_path / "electrosense.psm.json"
    res = CliRunner().invoke(cmd, ["--paper-table", "--symmetric", "-o", str(out)])
    assert res.exit_code == 0, res.output
    d = json.loads(out.read_text())
    assert {"radii_m", "centres_m", "emitter", "gamma_criterion", "reference"} <= set(d)
    assert len(d["radii_m"]) == 4 and d["emitter"] == 4 and d["centres_m"][0][0] > 0
    ref = tmp_path / "S.json"
    ref.write_text(json.dumps(paper_reference().to_json_dict()))
    out2 = tmp_path / "psm2.json"
    res = CliRunner().invoke(cmd, ["--reference", str(ref), "--symmetric", "-o", str(out2)])
    assert res.exit_code == 0, res.output
    assert json.loads(out2.read_text())["radii_m"] == pytest.approx(d["radii_m"], rel=1e-8)
    res = CliRunner().invoke(cmd, ["--reference", str(ref), "-o", str(out2)])
    assert res.exit_code != 0 and "--symmetric" in res.output
    d_tank = dict(paper_reference().to_json_dict(), unbounded=False, tank_size_m=[1.0, 1.0, 1.0])
    ref.write_text(json.dumps(d_tank))
    res = CliRunner().invoke(cmd, ["--reference", str(ref), "--symmetric", "-o", str(out2)])
    assert res.exit_code != 0 and "unbounded water" in res.output


def test_tank_reference_places_the_spheres_from_the_wall_effect():
    from electrosense.meshes.tank import Tank

    truth = PolySphericalModel.collinear([0.0072, 0.0072], [0.19])
    tank = Tank((1.0, 1.0, 1.0))
    poses = np.array([[-0.33, 0.0, 0.0, 0.0], [0.33, 0.0, 0.0, 0.0]])
    free = conductance(truth, np.zeros((1, 4)), SIGMA)[0]
    in_tank = conductance(truth, poses, SIGMA, tank, image_shells=4)
    with pytest.raises(CalibrationError, match="2 parameters"):
        calibrate(free, symmetric=True)  # free space alone cannot tell the length
    cal = calibrate(free, symmetric=True, tank_reference=(tank, poses, in_tank))
    np.testing.assert_allclose(cal.parameters, [0.0072, 0.19], rtol=1e-6)
    assert cal.model.info["fit"]["gamma_tank"] < 1e-8
