"""Sector electrodes in sensor files and meshes: numbering, refusals, labels, grading, exact symmetry."""
import json

import numpy as np
import pytest

from electrosense.meshes.quality import check_mesh
from electrosense.meshes.sector_mesh import block_symmetry, symmetry_order
from electrosense.meshes.sensor import Electrode, SensorDescription, load_sensor, preset, sector_azimuths_rad
from electrosense.meshes.sensor_mesh import mesh_sensor


def random_sector_sensor(seed: int) -> SensorDescription:
    """A sensor that is no preset: 3-5 electrodes, random sizes, a random choice of them split, random gaps."""
    rng = np.random.default_rng(seed)
    radius = rng.uniform(0.008, 0.014)
    length = rng.uniform(0.14, 0.24)
    half = length / 2
    n_rings = int(rng.integers(1, 4))
    cap = rng.uniform(0.4, 0.9) * radius
    room = np.linspace(half - radius - 0.004, -half + radius + 0.004, n_rings + 1)
    electrodes = [Electrode("cap", half - cap, half)]
    for a, b in zip(room[:-1], room[1:]):
        centre, width = 0.5 * (a + b), min(rng.uniform(0.004, 0.009), 0.6 * (a - b))
        electrodes.append(Electrode("ring", centre - width / 2, centre + width / 2))
    electrodes.append(Electrode("cap", -half, -half + cap))
    split = {}
    for k in range(1, len(electrodes)):   # the tail cap stays whole: it emits
        if rng.random() < 0.6 or not split and k == len(electrodes) - 1:
            split[k] = int(rng.integers(2, 7))
    gap = 0.0 if rng.random() < 0.3 else float(rng.uniform(0.0005, 0.003))
    base = SensorDescription(f"random-{seed}", radius, length, tuple(electrodes))
    return base.with_sectors(split, gap_m=gap)


def test_numbering_emitter_and_round_trip(tmp_path):
    s = preset("angels-4").with_sectors({2: 4, 3: 3}, gap_m=0.002)
    assert s.n_electrodes == 9 and s.emitter == 9            # the tail cap, numbered after every sector
    assert [s.sector_of(k) for k in (1, 2, 5, 6, 8, 9)] == [(0, 1), (1, 1), (1, 4), (2, 1), (2, 3), (3, 1)]
    assert s.numbers_of(2) == (6, 7, 8)
    assert s.electrode_labels == ("1", "2.1", "2.2", "2.3", "2.4", "3.1", "3.2", "3.3", "4")
    assert s.merged() == preset("angels-4")
    assert np.array_equal(s.merge_matrix().sum(axis=0), [1, 4, 3, 1])
    path = tmp_path / "s.json"
    path.write_text(json.dumps(s.to_dict()))
    assert load_sensor(path) == s
    assert "sectors" not in json.dumps(preset("angels-4").to_dict())   # whole electrodes are written as before
    toml = tmp_path / "s.toml"
    toml.write_text('[sensor]\nradius_m = 0.01\nlength_m = 0.2\nemitter = 3\n'
                    '[[sensor.electrodes]]\nkind = "cap"\nx_min_m = 0.09\nx_max_m = 0.1\nsectors = 2\n'
                    'sector_gap_m = 0.001\n[[sensor.electrodes]]\nkind = "cap"\nx_min_m = -0.1\nx_max_m = -0.09\n')
    t = load_sensor(toml)
    assert t.n_electrodes == 3 and t.emitter == 3 and t.sectors_touch   # a split cap's sectors meet at the tip


@pytest.mark.parametrize("change, words", [
    ({"sectors": 0}, "sectors 0"),
    ({"sectors": 2.5}, "sectors 2.5"),
    ({"sectors": True}, "sectors True"),
    ({"sectors": 2, "sector_gap_m": -0.001}, "sector_gap_m"),
    ({"sector_gap_m": 0.001}, "not split"),
    ({"sectors": 8, "sector_gap_m": 0.01}, "leave nothing"),
])
def test_refusals_name_the_electrode(change, words):
    d = preset("angels-4").to_dict()
    d["electrodes"][1].update(change)
    with pytest.raises(ValueError, match="electrode 2") as err:
        SensorDescription.from_dict(d)
    assert words in str(err.value)


def test_emitter_numbering_refusal():
    with pytest.raises(ValueError, match="emitter 6 is not an electrode number"):
        preset("angels-4").with_sectors({2: 2}, emitter=6)


def test_sector_azimuths_sector_one_on_plus_y():
    centres, half = sector_azimuths_rad(Electrode("ring", -0.01, 0.01, 3, 0.003), 0.01)
    assert centres[0] == 0 and half == pytest.approx(np.pi / 3 - 0.15)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_random_sensors_mesh_watertight_labelled_symmetric(seed):
    s = random_sector_sensor(seed)
    m = mesh_sensor(s, edge_length_m=1.2 * s.radius_m)
    assert m.to_trimesh().is_watertight
    assert m.electrodes == tuple(range(1, s.n_electrodes + 1))
    check_mesh(m, min_angle_deg=1.0, max_aspect_ratio=60.0)
    # every sector has the area its arc and extent give (the faceted rings enclose the circles' areas)
    areas = np.bincount(m.electrode, m.areas_m2)[1:]
    for j, e in enumerate(s.electrodes):
        numbers = np.asarray(s.numbers_of(j)) - 1
        if e.is_split and e.kind == "ring":
            half = sector_azimuths_rad(e, s.radius_m)[1]
            expected = 2 * half * s.radius_m * (e.x_max_m - e.x_min_m)
            assert areas[numbers] == pytest.approx(expected, rel=0.03)
        if e.is_split:   # the sectors of one electrode are meshed alike
            assert np.ptp(areas[numbers]) < 1e-9 * areas[numbers].max()
    # exact symmetry: the copies of the first block are rotated (or mirrored) copies of it
    order, mirror = block_symmetry(s)
    tri = m.triangles_m
    n = len(tri) // order
    c0 = tri[:n].mean(axis=1)
    for a in range(1, order):
        if mirror:
            turned = c0 * [1, 1, -1]
        else:
            c, si = np.cos(2 * np.pi * a / order), np.sin(2 * np.pi * a / order)
            turned = np.column_stack([c0[:, 0], c * c0[:, 1] - si * c0[:, 2], si * c0[:, 1] + c * c0[:, 2]])
        assert np.abs(turned - tri[a * n:(a + 1) * n].mean(axis=1)).max() < 1e-12


def test_grading_towards_sector_edges():
    s = preset("angels-4").with_sectors({2: 4}, gap_m=0.002)
    m = mesh_sensor(s)
    e = s.electrodes[1]
    on = np.isin(m.electrode, s.numbers_of(1))
    phi = np.arctan2(m.centroids_m[on, 2], m.centroids_m[on, 1])
    centres, half = sector_azimuths_rad(e, s.radius_m)
    to_edge = np.min(np.abs(np.abs((phi[:, None] - centres[None] + np.pi) % (2 * np.pi) - np.pi) - half), axis=1)
    width = np.ptp(np.arctan2(m.triangles_m[on][:, :, 2], m.triangles_m[on][:, :, 1]), axis=1)
    near, far = to_edge < 0.02, to_edge > 0.3
    assert width[near].max() < 0.25 * np.median(width[far])    # finer around the sector edges


def test_symmetry_orders():
    assert symmetry_order(preset("angels-4").with_sectors({2: 4, 3: 6})) == 2
    assert block_symmetry(preset("angels-4").with_sectors({2: 2, 3: 3})) == (2, True)
    assert block_symmetry(preset("angels-4").with_sectors({1: 3})) == (3, False)


def test_lateral_weights_left_minus_right():
    s = preset("angels-4").with_sectors({2: 2, 3: 3})
    split, W = s.lateral_weights()
    assert split == (1, 2)
    assert W[0, 1:3].tolist() == [1.0, -1.0] and W[1, 3:6].round(12).tolist() == [1.0, -0.5, -0.5]
