"""The sector PSM: file round trip, its image kernel, and against the BEM in a tank (coarse meshes)."""
import numpy as np
import pytest

from electrosense.bem.lateral import free_space_response
from electrosense.meshes import Tank, preset
from electrosense.psm.images import image_sources
from electrosense.psm.sectors import (
    SectorModel,
    _stencil,
    _to_tank,
    reflected_potential,
    reflection_kernel,
    sector_conductance,
)

COARSE = 0.02
SENSOR = preset("angels-4").with_sectors({2: 4}, gap_m=0.002)


@pytest.fixture(scope="module")
def model():
    return SectorModel.from_response(free_space_response(SENSOR, 0.0354, edge_length_m=COARSE))


def test_round_trip_and_free_space(model, tmp_path):
    model.save(tmp_path / "m.json")
    again = SectorModel.load(tmp_path / "m.json")
    assert np.array_equal(again.K0_S, model.K0_S) and np.array_equal(again.dipole_response_S_m2,
                                                                       model.dipole_response_S_m2)
    K = sector_conductance(again, [[0.1, 0.2, 0.0, 1.0]], 0.0354).K_S[0]
    assert np.allclose(K, 0.5 * (model.K0_S + model.K0_S.T))
    with pytest.raises(ValueError, match="not a sector model"):
        SectorModel.from_json_dict({"model": "poly-spherical"})


def test_image_kernel_against_central_differences():
    centres = np.array([[0.09, 0, 0], [0.03, 0.011, 0], [0.03, 0, 0.011], [-0.09, 0, 0]])
    poses = np.array([[0.1, 0.4, 0.05, 0.7]])
    images = image_sources(Tank((1.0, 1.0, 1.0)), "complete", 4)
    psi = reflection_kernel(centres, poses, 1.0, images, np.zeros((0, 3)), np.zeros(0))
    h = 1e-4
    points = _to_tank(_stencil(centres), poses)
    phi = reflected_potential(points, points, images, np.zeros((0, 3)), np.zeros(0)).reshape(1, 4, 7, 4, 7)

    def taylor(a):
        return np.stack([a[..., 0], (a[..., 1] - a[..., 2]) / (2 * h), (a[..., 3] - a[..., 4]) / (2 * h),
                         (a[..., 5] - a[..., 6]) / (2 * h)], axis=-1)

    ref = taylor(taylor(phi).transpose(0, 1, 3, 4, 2)).transpose(0, 1, 4, 2, 3).reshape(1, 16, 16) / (4 * np.pi)
    assert np.abs(psi - ref).max() < 1e-4 * np.abs(ref).max()
    assert np.abs(psi - psi.transpose(0, 2, 1)).max() < 1e-12 * np.abs(psi).max()   # reciprocity


def test_against_the_bem_beside_a_wall(model):
    from electrosense.bem.sweep import PoseSweep

    d = 0.5 - SENSOR.radius_m - np.array([0.03, 0.06])
    poses = np.array([[0.05, d[0], 0, 0], [0.05, d[1], 0, 0], [0.05, -d[0], 0, 0]])
    tank = Tank((1.0, 1.0, 1.0))
    bem = PoseSweep(SENSOR, tank, sigma_S_per_m=0.0354, edge_length_m=COARSE).conductance(poses).K_S
    psm = sector_conductance(model, poses, 0.0354, tank).K_S
    e = SENSOR.emitter - 1
    Ib, Ip = -bem[:, :, e], -psm[:, :, e]
    receivers = [k - 1 for k in SENSOR.receivers]
    assert np.abs(Ip[:, receivers] / Ib[:, receivers] - 1).mean() < 0.01
    lat_b, lat_p = Ib[:, 1] - Ib[:, 3], Ip[:, 1] - Ip[:, 3]
    assert np.sqrt(np.mean((lat_p - lat_b) ** 2) / np.mean(lat_b ** 2)) < 0.1
    assert lat_p[0] * lat_p[2] < 0       # the lateral signal changes sign with the wall's side


def test_the_model_door_gives_the_sector_psm(tmp_path, monkeypatch):
    from electrosense.psm import PolySphericalModel
    from electrosense.validation.simulation.models import ModelError, pose_evaluator

    monkeypatch.setenv("ESENSE_CACHE_DIR", str(tmp_path))
    tank = Tank((1.0, 1.0, 1.0))
    ev = pose_evaluator("psm", SENSOR, tank, 0.0354, edge_length_m=COARSE)
    C = ev.conductance(np.array([[0.0, 0.4, 0.0, 0.0]]))
    assert C.K_S.shape == (1, 7, 7) and ev.info["model"] == "psm-sectors"
    assert list(tmp_path.glob("psm/psm-sectors-*.json"))      # calibrated once, cached
    with pytest.raises(ModelError, match="sector model"):
        pose_evaluator("psm", SENSOR, tank, 0.0354, psm_model=PolySphericalModel.collinear([0.007] * 2, [0.2]))
