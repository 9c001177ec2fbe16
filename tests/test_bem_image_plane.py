"""A flat face of the tank as an image plane in the Green's function (electrosense.bem.image_plane).

Checked against the BEM with that face meshed: far from the face the two agree to the coupling's truncation;
next to it the meshed BEM's error (its tank mesh's, largest beside the sensor) shrinks towards the image as its
mesh there is refined (its edge bounded by a smaller multiple of its distance from the sensor); the currents are conserved, which a face left out without its image would break.
"""
import numpy as np
import pytest

from electrosense.bem import PoseSweep
from electrosense.bem.image_plane import ImageFaceError, split_image_faces
from electrosense.meshes import Tank, preset
from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.tank_mesh import mesh_tank

SENSOR = preset("angels-2")
EDGE_M = 0.012          # a coarse sensor mesh: the image's term is checked, not the sensor's discretisation


def _K(tank, pose, **options):
    g = PoseSweep(SENSOR, tank, sigma_S_per_m=1.0, edge_length_m=EDGE_M, tol=1e-6, block_cache=False,
                  edge_correction=False, **options).conductance(np.asarray(pose, float)[None])
    return g.K_S[0], g


def _random_box(rng):
    return Tank(tuple(rng.uniform([0.3, 0.22, 0.14], [0.45, 0.3, 0.2])))


def test_far_from_the_face_the_image_is_the_mesh():
    rng = np.random.default_rng(3)
    tank = Tank((rng.uniform(0.6, 0.7), 0.25, 0.18))
    pose = [0.5 * tank.size_m[0] - 0.15, 0.0, 0.0, rng.uniform(-0.2, 0.2)]    # the face 0.3-0.4 m away
    K_meshed, _ = _K(tank, pose)
    K_image, g = _K(tank, pose, image_face="wall_x-")
    assert np.abs(K_image - K_meshed).max() < 5e-5 * np.abs(K_meshed).max()
    assert g.info["triangles"] < _K(tank, pose)[1].info["triangles"]      # one face fewer


@pytest.mark.slow      # 7-10 s each: out of the default run, which must stay under 10 min (-m slow)
@pytest.mark.parametrize("seed", [0, 1])
def test_next_to_the_face_the_meshed_bem_converges_to_the_image(seed):
    rng = np.random.default_rng(seed)
    tank = _random_box(rng)
    face = ("wall_y-", "wall_y+")[seed]
    gap, yaw = rng.uniform(0.004, 0.008), rng.uniform(-0.05, 0.05)
    reach = SENSOR.radius_m + (0.5 * SENSOR.length_m - SENSOR.radius_m) * abs(np.sin(yaw))
    y = (0.5 * tank.size_m[1] - reach - gap) * (-1 if face == "wall_y-" else 1)
    pose = [rng.uniform(-0.03, 0.03), y, 0.0, yaw]     # alongside the wall, its nearest point gap away
    errors = []
    for ratio in (0.7, 0.35):     # the rest of the tank meshed alike: the difference is the face's mesh's
        K_image, g = _K(tank, pose, image_face=face, tank_near_ratio=ratio)
        K_meshed, _ = _K(tank, pose, tank_near_ratio=ratio)
        errors.append(np.abs(K_meshed - K_image).max() / np.abs(K_image).max())
    assert errors[0] > 1.5 * errors[1], errors
    assert errors[1] < 1e-3, errors
    # conservation and reciprocity of the image's system: a closed tank's currents sum to zero
    assert g.row_sum_residue < 1e-4      # the meshed BEM: 1e-5 (the far field's centroid rule)
    assert g.asymmetry < 5e-3


def test_a_cylinders_floor_is_an_image_plane_and_its_wall_is_not():
    tank = CylinderTank(0.15, 0.2)
    pose = [0.0, 0.0, tank.floor_z_m + SENSOR.radius_m + 0.006, 0.3]    # lying 6 mm above the floor
    K_image, g = _K(tank, pose, image_face="floor", tank_near_ratio=0.7)
    K_meshed, _ = _K(tank, pose, tank_near_ratio=0.7)
    assert np.abs(K_image - K_meshed).max() < 2e-3 * np.abs(K_meshed).max()
    assert g.row_sum_residue < 1e-4      # the meshed BEM: 1e-5 (the far field's centroid rule)
    with pytest.raises(ImageFaceError, match="'wall' is not flat"):
        _K(tank, [0.0, 0.0, 0.0, 0.0], image_face="wall")


@pytest.mark.slow      # 10 s: out of the default run, which must stay under 10 min (-m slow)
def test_a_corner_takes_both_walls_and_their_product_as_images():
    rng = np.random.default_rng(7)
    tank = _random_box(rng)
    lo, hi = tank.water_bounds_m
    half = 0.5 * SENSOR.length_m
    pose = [hi[0] - half - 0.006, lo[1] + SENSOR.radius_m + 0.008, 0.0, 0.0]   # its tip 6 mm from x+, side 8 mm from y-
    K_two, g = _K(tank, pose, image_face=("wall_x+", "wall_y-"), tank_near_ratio=0.7)
    K_two_finer, _ = _K(tank, pose, image_face=("wall_x+", "wall_y-"))
    K_meshed = [_K(tank, pose, tank_near_ratio=r)[0] for r in (0.7, 0.35)]
    scale = np.abs(K_two).max()
    # the walls' meshes converge towards the images (measured: 0.36 / 0.14 / 0.02 % off them at 0.7 / 0.35 /
    # 0.2), and the images do not depend on how the rest of the tank is meshed
    error = [np.abs(K - K_two).max() / scale for K in K_meshed]
    assert error[0] > 2 * error[1], error
    assert np.abs(K_two_finer - K_two).max() < 1e-4 * scale
    assert g.row_sum_residue < 1e-4
    with pytest.raises(ImageFaceError, match="'wall_x\\+' and 'wall_x-' are not perpendicular"):
        _K(tank, pose, image_face=("wall_x+", "wall_x-"))


def test_refusals_name_the_face():
    mesh = mesh_tank(Tank((0.3, 0.2, 0.2)), 0.05)
    with pytest.raises(ImageFaceError, match="no face 'wall_z'.*wall_x-"):
        split_image_faces(mesh, ("wall_z",))
    with pytest.raises(ValueError, match="unbounded water has no faces"):
        PoseSweep(SENSOR, None, edge_length_m=EDGE_M, image_face="floor")
    with pytest.raises(ValueError, match="image plane, not a mesh"):
        PoseSweep(SENSOR, Tank((0.3, 0.2, 0.2)), edge_length_m=EDGE_M, edge_correction=False,
                  image_face="floor").conductance([[0.0, 0.0, 0.0, 0.0]], wall_derivatives=True)
