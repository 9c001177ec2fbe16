"""Where the gap lies: shares, concentration, time trend."""
import numpy as np
import pytest

from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.observations import Observations
from electrosense.validation.diagnosis.where import breakdown, place_labels, region_mask


def _line(n=80, t_step=10.0):
    x = np.linspace(-0.38, 0.38, n)
    poses = np.column_stack([x, 0 * x, 0 * x, 0 * x])
    return Observations(poses, np.ones((n, 3)), preset("angels-4"), Tank((1, 1, 1)), 0.0354,
                        t_s=np.arange(n) * t_step)


def test_shares_add_up_and_enrichment_is_one_for_an_even_gap():
    obs = _line()
    r = np.full((obs.n_poses, 3), 0.01)
    w = breakdown(obs, r)
    for axis in ("by_receiver", "by_place", "by_time", "by_heading", "by_pass"):
        assert sum(row["share"] for row in w[axis]) == pytest.approx(1.0)
        assert sum(row["n"] for row in w[axis]) == r.size
    assert all(row["enrichment"] == pytest.approx(1.0) for row in w["by_receiver"])


def test_gap_near_one_wall_is_found_there():
    obs = _line()
    x = obs.poses[:, 0]
    r = np.where(x[:, None] > 0.3, 0.02, 0.0) + np.zeros((obs.n_poses, 3))
    w = breakdown(obs, r)
    assert w["concentration"]["axis"] == "place" and w["concentration"]["group"] == "wall_x+"
    assert w["concentration"]["share"] == pytest.approx(1.0)
    mask = region_mask(w)
    assert np.all(mask[x > 0.3]) and not np.any(mask[x < 0])


def test_place_labels_name_the_nearest_boundary_within_reach():
    obs = _line()
    labels = place_labels(obs, near_m=0.12)
    assert labels[0] == "wall_x-" and labels[-1] == "wall_x+" and labels[len(labels) // 2] == "mid_tank"


def test_time_trend_slope_is_recovered():
    obs = _line(t_step=45.0)  # one hour
    t_h = (obs.t_s - obs.t_s.mean()) / 3600
    r = (0.01 * t_h)[:, None] + np.zeros((obs.n_poses, 3))
    trend = breakdown(obs, r)["time_trend"]
    assert trend["slope_per_hour"] == pytest.approx(0.01, rel=1e-6)
