"""A tank map: the BEM's K over every pose a robot can reach at one depth (or a band), interpolated, with its error.

The PSM is fast but a percent off the BEM in a tank it was not calibrated
for, most of it near the walls, where a robot needs it most. A map is built
once per sensor, tank (box or cylinder, with its fixed objects) and depth:

1. the candidate poses: (x, y, heading) on a grid at depth ``z_m`` (or
   several depths of a band) with the sensor's surface at least
   ``wall_gap_m`` from every wall, floor, surface and object
   (:func:`reachable_poses`), and the grid's poses whose tip faces a wall or
   object moved until the tip is at that gap (:func:`tips_at_the_gap`), those
   near two walls moved to that gap from both (:func:`corners_at_the_gap`) and,
   in a box, poses at random gaps from two walls (:func:`corner_poses`),
   folded into the tank's fundamental domain
   (:mod:`.map_coordinates`);
2. the BEM as a user runs it at one pose (:class:`electrosense.bem.PoseSweep`,
   the sensor's block shared, each pose on a tank mesh graded to it alone,
   its edge bounded by the distance from the sensor, the sensor-tank coupling
   truncated at :data:`MAP_COUPLING_TOL`; on ``workers`` processes) at a
   first spread of them
   (farthest-point sampling in the map's warped coordinates, which crowds
   them near the walls), then, round after round, at the candidates of
   largest estimated error (and a share of each round, :data:`EXPLORE_SHARE`,
   spread over the tank: that estimate runs low mid-tank), until it is below
   the target (a third of the bench noise, RMS and max) or the time is spent;
3. log(K_bem / K_free) of every electrode pair interpolated over the
   warped coordinates (quintic radial basis functions with a quadratic trend,
   :class:`~electrosense.validation.diagnosis.anchored.RBFInterpolant`, and,
   where the leave-one-out errors favour them, the walls' mirror images of the
   electrodes and their powers as linear regressors: :meth:`TankMap._fit_coarse`), its
   leave-one-out error at every node (a node and its mirror images across the fold's faces left out together),
   and the error estimated anywhere from
   the nearest nodes' (:func:`~electrosense.validation.diagnosis.anchored.estimated_error`);
   the many poses are solved on a coarser sensor mesh, and the correction to
   the reference sensor mesh, known at fewer poses, is interpolated as a linear
   function of the coarse K of the emitter's pairs plus a smooth remainder of
   the pose (the discretisation's error near a wall grows with the wall's
   effect), or of the pose alone, whichever its leave-one-out errors favour
   (:meth:`TankMap._fit_correction`). The reference is also the finer tank
   mesh (:data:`REFERENCE_TANK_GRADING`), and the coarse poses' tank mesh is
   coarser near a wall (:data:`COARSE_TANK_NEAR_RATIO`: such a pose costs its
   tank mesh); at both kinds of pose the tank's flat faces near the sensor are
   image planes instead of meshes (:func:`image_faces_near`; exact, where a
   meshed wall beside the sensor converges slowly), so that the correction
   carries the sensor mesh's error and the far faces' mesh error.

The map is one ``.npz`` file: the nodes, the BEM's K there, the interpolant's
coefficients, the scene, the sensor, the BEM options and the code version;
loading it reads arrays (milliseconds). A killed build resumes from the nodes
saved after each round. :meth:`TankMap.conductance` evaluates K and its pose
Jacobian for many poses in one vectorised call.

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.tank import Tank
>>> P = reachable_poses(preset("angels-4"), Tank((1.0, 1.0, 1.0)), 0.0, spacing_m=0.1, n_headings=4)
>>> P.shape[1], bool(abs(P[:, 0]).max() < 0.5)
(4, True)
"""
from __future__ import annotations

import json
import os
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.bem.conductance import pair_values
from electrosense.validation.simulation.map_coordinates import DEFAULT_WARP_M, MapFrame
from electrosense.validation.simulation.workers import exit_with_parent, one_thread

__all__ = ["TankMap", "MapEvaluator", "reachable_poses", "tips_at_the_gap", "corners_at_the_gap", "boundary_gaps_m",
           "sensor_wall_gap_m", "image_faces_near", "build_tank_map", "load_tank_map", "MAP_FORMAT", "scene_record",
           "scene_from_record", "same_scene"]

MAP_FORMAT = "electrosense tank map 12"   # 12: the correction's own warp (11: the BEM's edge correction scaled
#: into each pose's scene; 10: the reference poses' near faces image planes; 9: the fixed objects' images; 8: the
#: edges' images a group of their own); earlier formats read as they are where nothing but the format changed: 11
#: (its correction at the map's warp), 10 (its BEM's edge correction a constant), 9 (its reference every face
#: meshed), 8 without fixed objects (format 8 with objects: its interpolants fitted again from its nodes, which
#: are kept)
READABLE_FORMATS = (MAP_FORMAT, "electrosense tank map 11", "electrosense tank map 10", "electrosense tank map 9",
                    "electrosense tank map 8")

#: the interpolant's trend degree: 2, a quintic kernel r^5 with a quadratic trend (1: r^3, linear), which on 400 BEM
#: poses of a random 5-electrode sensor came 1.4x closer to the BEM at fresh poses (:class:`RBFInterpolant`)
RBF_DEGREE = 2

#: the powers of the walls' images taken as regressors beside the first (:meth:`TankMap._fit_coarse`): log K is
#: a series in the image terms, of which the first power is the leading one. On the seed-4 study's map (250 BEM
#: poses; 140 fresh poses, 29 of them within 3 cm of a wall, on the coarse BEM the interpolant reproduces) the
#: powers 1-3 came 0.034 % RMS / 0.19 % max against 0.045 % / 0.33 % with the first alone (within 3 cm 0.066 %
#: against 0.086 %; leave-one-out 0.090 % against 0.109 %); powers 1-2: 0.040 % / 0.27 %; log(1 + R): 0.043 %
#: / 0.29 %; the warp's length from 0.5 to 4 mm changed the RMS by under 0.001 %
IMAGE_POWERS = 3

#: the fewest reference poses a map with a coarse sensor mesh is built with, whatever its budget: its correction
#: and the correction's estimated error need some
MIN_REFERENCE_POSES = 4

#: the share of each round's coarse poses spread over the tank (farthest from every node in the tips' positions)
#: rather than put where the estimated error is largest: that estimate is right on average but too high at the
#: walls and 2-3x too low mid-tank (a random 5-electrode sensor's map, four fresh poses 6-9 cm from the walls),
#: so rounds led by it alone leave mid-tank sparse
EXPLORE_SHARE = 1.0 / 3.0

#: the share of each round of reference poses spread over the tank (farthest from the reference poses in the tips'
#: positions) rather than put at the nodes where the correction's estimated error is largest: those are near the
#: walls, where the correction is largest and a reference pose costs most, and a build led by them alone put 31 of
#: its 44 reference poses within 13 mm of a wall and left the middle of the tank to a few, where most of a random
#: pose's error was then the correction's (seed 4's study box: at 40 random poses the correction 0.018 % RMS of
#: 0.020 %, the coarse interpolation 0.014 %). With half of each round spread, the same 540 s of CPU: 0.016 % RMS
#: (correction 0.014 %), near the walls 0.071 % against 0.068 % at 40 poses 5-15 mm from one; another draw's
#: 4-electrode sensor in a 0.70 x 0.43 m box (seed 6): 0.018 % / 0.120 % -> 0.014 % / 0.085 % at 40 random poses,
#: near the walls 0.023 % -> 0.021 %, and 475 BEM poses where 420 were bought (a reference pose mid-tank costs
#: less than one at a wall). The tank-map studies (20 fresh poses): seed 4 0.019 % / 0.071 % -> 0.017 % / 0.055 %,
#: near the walls 0.119 % / 0.338 % -> 0.091 % / 0.243 %; angels-4 in the 1 m tank 0.012 % / 0.057 % -> 0.017 % /
#: 0.093 % (its maximum, a tip 5.6 mm from a wall, now the correction's: fewer reference poses at the walls), near
#: the walls 0.043 % / 0.086 % -> 0.031 % / 0.065 %
REFERENCE_SPREAD_SHARE = 0.5

#: a node's mirror image across a face of the fold joins the interpolants' nodes where it lies within this many
#: times the node's distance to its nearest other node (:meth:`MapFrame.mirror_ghosts`). Refitted offline on seed
#: 4's finished map (reach 0 / 2 / 3 / 5): 16 tips 5-7 mm from the middle of a wall 0.103 / 0.054 / 0.054 / 0.038 %
#: at most, 36 square-on tips 0.111 / 0.066 / 0.060 / 0.073 %, 8 near-wall poses 0.085 / 0.128 / 0.106 / 0.114 %;
#: seed 2's corner pose 0.107 / 0.127 / 0.147 / 0.167 % (its 19 others 0.025 % -> 0.011 % at most in the study)
GHOST_REACH = 3.0

#: the warps (times the map's ``warp_m``) the reference correction is fitted at, the one closest at left-out
#: reference poses kept (:meth:`TankMap._fit_correction_warped`): the correction log(K_ref / K_coarse) changes
#: less sharply at a wall than K itself, and the map's 1 mm warp stretched its nodes' few near-wall poses apart.
#: Refitted on four built maps (seeds 21 and 4; 54-100 reference poses), 10 mm was closest at left-out reference
#: poses on all four (0.0240-0.0353 % against 0.0276-0.0370 % at 1 mm) and the maps' error at their studies' 8
#: poses 5-15 mm from a wall fell to 0.0236 / 0.0271 / 0.0358 / 0.0579 % from 0.0293 / 0.0350 / 0.0366 / 0.0594 %,
#: the fresh poses' and the corners' within 0.001 %; at 30 mm the left-out error and the fresh poses were worse
CORRECTION_WARP_FACTORS = (1.0, 3.0, 10.0)

#: the arrays of a map's reference correction, in its ``fitted`` dict and its file (a map without a correction
#: has none; ``warp_ref`` from format 12)
REFERENCE_KEYS = ("X_ref", "coef_ref", "loo_ref", "regressors_ref", "warp_ref")

#: relative error targets of the receiver currents: a third of the bench noise (RMS) and 0.05 % at most
TARGET_RMS = 1.7e-4
TARGET_MAX = 5e-4


# ------------------------------------------------------------------ poses
def _axis_points(sensor, poses, n_axis: int = 9) -> np.ndarray:
    from electrosense.meshes.pose import sensor_to_tank

    half = 0.5 * sensor.length_m - sensor.radius_m
    axis = np.c_[np.linspace(-half, half, n_axis), np.zeros(n_axis), np.zeros(n_axis)]
    return sensor_to_tank(axis, np.asarray(poses, float).reshape(-1, 4))  # (P, n_axis, 3)


def boundary_gaps_m(sensor, tank, poses: np.ndarray, objects=(), n_axis: int = 9) -> np.ndarray:
    """(P, B) the distance (m) from the sensor's surface (a cylinder of its radius with round ends) to each of the
    tank's boundaries (its walls, floor and free surface, ordered as ``tank.distance_to_boundary_m``; none for
    unbounded water) and to each of the fixed ``objects`` after them, sampled at ``n_axis`` points of its axis
    (a distance is 1-Lipschitz along it: the true gap is at most half the samples' spacing below)."""
    from electrosense.meshes.scene_mesh import distance_to_object_m

    pts = _axis_points(sensor, poses, n_axis)
    gaps = [np.zeros((len(pts), 0)) if tank is None else tank.distance_to_boundary_m(pts).min(axis=1)]
    gaps += [distance_to_object_m(obj, pts).min(axis=1)[:, None] for obj in objects]
    return np.hstack(gaps) - sensor.radius_m


def sensor_wall_gap_m(sensor, tank, poses: np.ndarray, objects=()) -> np.ndarray:
    """(P,) the smallest distance (m) from the sensor's surface (a cylinder of its radius with round ends) to the
    tank's walls, floor and free surface, and to the fixed ``objects``."""
    return boundary_gaps_m(sensor, tank, poses, objects).min(axis=1)


def reachable_poses(sensor, tank, z_m, wall_gap_m: float = 0.005, spacing_m: float = 0.01, n_headings: int = 48,
                    objects=()) -> np.ndarray:
    """(C, 4) poses (x, y, z, yaw) on a grid of ``spacing_m``, ``n_headings`` headings over the full turn and the
    depths ``z_m`` (one or several), with the sensor's surface at least ``wall_gap_m`` from every boundary."""
    lo, hi = tank.water_bounds_m
    xs = np.arange(lo[0] + wall_gap_m, hi[0] - wall_gap_m + 1e-12, spacing_m)
    ys = np.arange(lo[1] + wall_gap_m, hi[1] - wall_gap_m + 1e-12, spacing_m)
    yaws = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    zs = np.atleast_1d(np.asarray(z_m, float))
    X, Y, Z, W = np.meshgrid(xs, ys, zs, yaws, indexing="ij")
    P = np.c_[X.ravel(), Y.ravel(), Z.ravel(), W.ravel()]
    return P[sensor_wall_gap_m(sensor, tank, P, objects) >= wall_gap_m]


def _gaps_and_gradient(sensor, tank, poses: np.ndarray, objects=(), h_m: float = 1e-5):
    """:func:`boundary_gaps_m` at ``poses`` (P, B) and its gradient by the pose's x and y, (P, B, 2), by forward
    differences of ``h_m`` (exact for a flat wall's gap, linear in x and y)."""
    G = boundary_gaps_m(sensor, tank, poses, objects)
    step = lambda d: boundary_gaps_m(sensor, tank, poses + d, objects)   # noqa: E731
    return G, np.stack([(step(np.r_[h_m, 0.0, 0.0, 0.0]) - G) / h_m,
                        (step(np.r_[0.0, h_m, 0.0, 0.0]) - G) / h_m], axis=-1)


def tips_at_the_gap(sensor, tank, poses: np.ndarray, wall_gap_m: float, within_m: float, objects=(),
                    facing_rad: float = np.pi / 8, steps: int = 3) -> np.ndarray:
    """(Q, 4) the ``poses`` whose sensor's tip faces a wall or object (its axis within ``facing_rad`` of the
    boundary's normal) within ``within_m`` of the gap ``wall_gap_m``, moved across the water (x, y; depth and
    heading kept) until that tip is at the gap exactly.

    A grid of spacing h puts a tip anywhere from the gap to the gap + h from a wall (a 1 cm grid, seed 4's
    sensor tip-on: 9.5 mm at the closest), and log K changes fastest there (0.1-0.17 % between 5 and 7 mm):
    the tips at the gap are the poses a map's interpolation misses unless it is given them. The move is a
    Newton step on the boundary's gap along its gradient in (x, y) (finite differences: exact in one for a flat
    wall, three for a round one); the floor and the free surface, flat across the water, are not moved to; a
    pose that would come nearer another boundary than the gap is dropped.

    >>> from electrosense.meshes import preset
    >>> from electrosense.meshes.tank import Tank
    >>> sensor, tank = preset("angels-4"), Tank((1.0, 1.0, 1.0))
    >>> P = np.array([[0.385, 0.0, 0.0, 0.0], [0.0, 0.38, 0.0, 0.0]])   # a tip 15 mm from a wall; side-on
    >>> Q = tips_at_the_gap(sensor, tank, P, 0.005, 0.02)
    >>> Q.round(4).tolist(), np.round(1e3 * sensor_wall_gap_m(sensor, tank, Q), 6).tolist()
    ([[0.395, 0.0, 0.0, 0.0]], [5.0])
    """
    poses = np.asarray(poses, float).reshape(-1, 4)
    gaps = lambda P: boundary_gaps_m(sensor, tank, P, objects)   # noqa: E731
    gradient = lambda P: _gaps_and_gradient(sensor, tank, P, objects)   # noqa: E731

    G, D = gradient(poses)
    norm = np.linalg.norm(D, axis=-1)
    axis = np.c_[np.cos(poses[:, 3]), np.sin(poses[:, 3])]
    facing = np.abs(np.einsum("pbi,pi->pb", D, axis)) >= np.cos(facing_rad) * norm
    near = (G < wall_gap_m + within_m) & (norm > 0.5) & facing   # walls and objects, not the floor
    target = wall_gap_m * (1.0 + 1e-9) + 1e-12
    out = []
    for b in np.flatnonzero(near.any(axis=0)):
        P = poses[near[:, b]].copy()
        for _ in range(steps):
            G, D = gradient(P)
            P[:, :2] += ((target - G[:, b]) / np.sum(D[:, b] ** 2, axis=1))[:, None] * D[:, b]
        G = gaps(P)
        out.append(P[(G.min(axis=1) >= wall_gap_m) & (np.abs(G[:, b] - target) < 1e-6)])
    return np.vstack(out) if out else np.zeros((0, 4))


def corners_at_the_gap(sensor, tank, poses: np.ndarray, wall_gap_m: float, within_m: float, objects=(),
                       steps: int = 3) -> np.ndarray:
    """(Q, 4) the ``poses`` near two boundaries at once that meet at an angle (two walls of a box at a corner, a
    wall and an object), each within ``within_m`` of the gap ``wall_gap_m``, moved across the water (x, y; depth
    and heading kept) until the sensor is at that gap from both.

    Where the sensor's tip and side (or both ends) are near two walls, log K depends on the two gaps together,
    and the grid's poses, a spacing apart, leave that corner to the interpolant: at 24 random poses of seed 2's
    study box with two walls each 5-12 mm from the sensor, its map (500 BEM poses, none such) erred 0.079 % RMS,
    0.35 % at most, on its own coarse BEM; 30 coarse poses at the gap from both walls, headings spread, took
    that to 0.032 % / 0.072 % (60: 0.029 % / 0.065 %; 24 at random corner poses instead: 0.051 % / 0.23 %).
    In the studies' built maps they took seed 2's worst fresh pose (8 mm from two walls) from 0.162 % to 0.023 %,
    but not the corners at large: against the reference BEM at 24 random corner poses seed 2 0.073 % / 0.18 % ->
    0.076 % / 0.22 %, seed 4 0.076 % / 0.23 % -> 0.079 % / 0.23 % (a build spends its budget otherwise once it has
    them; README, the tank map's corners). The move is a Newton step on both gaps along their gradients in (x, y) (:func:`tips_at_the_gap`'s finite
    differences; exact in one for two flat walls); two boundaries whose gradients are within 30 degrees of
    parallel (two opposite walls, a round wall) are not a corner; a pose that would come nearer another
    boundary than the gap is dropped.

    >>> from electrosense.meshes import preset
    >>> from electrosense.meshes.tank import Tank
    >>> sensor, tank = preset("angels-4"), Tank((1.0, 1.0, 1.0))
    >>> P = np.array([[0.38, 0.47, 0.0, 0.0]])           # the tip 20 mm from the +x wall, a side 17.8 from +y
    >>> Q = corners_at_the_gap(sensor, tank, P, 0.005, 0.03)
    >>> np.round(1e3 * boundary_gaps_m(sensor, tank, Q)[0, [1, 3]], 6).tolist()
    [5.0, 5.0]
    """
    poses = np.asarray(poses, float).reshape(-1, 4)
    gaps = lambda P: boundary_gaps_m(sensor, tank, P, objects)   # noqa: E731
    gradient = lambda P: _gaps_and_gradient(sensor, tank, P, objects)   # noqa: E731

    G, D = gradient(poses)
    norm = np.linalg.norm(D, axis=-1)
    near = (G < wall_gap_m + within_m) & (norm > 0.5)   # walls and objects, not the floor
    target = wall_gap_m * (1.0 + 1e-9) + 1e-12
    out = []
    for a in range(G.shape[1]):
        for b in range(a + 1, G.shape[1]):
            both = near[:, a] & near[:, b]
            cos = np.einsum("pi,pi->p", D[:, a], D[:, b]) / np.maximum(norm[:, a] * norm[:, b], 1e-12)
            P = poses[both & (np.abs(cos) < np.cos(np.pi / 6))].copy()
            if not len(P):
                continue
            for _ in range(steps):
                G2, D2 = gradient(P)
                J = D2[:, [a, b]]                                            # (P, 2, 2)
                r = target - G2[:, [a, b]]
                ok = np.abs(np.linalg.det(J)) > 0.25
                P, J, r = P[ok], J[ok], r[ok]
                P[:, :2] += np.linalg.solve(J, r[..., None])[..., 0]
            G2 = gaps(P)
            out.append(P[(G2.min(axis=1) >= wall_gap_m) & (np.abs(G2[:, a] - target) < 1e-6)
                         & (np.abs(G2[:, b] - target) < 1e-6)])
    return np.vstack(out) if out else np.zeros((0, 4))


#: the band of gaps from two walls of a box's corner poses drawn at random (:func:`corner_poses`), as multiples of
#: the map's wall gap: 5-12 mm at the default 5 mm
CORNER_BAND = (1.0, 2.4)
#: the build's candidates in that band: this many times the first round's share of them, drawn from this seed
CORNER_BAND_CANDIDATES, CORNER_BAND_SEED = 8, 20261130


def corner_poses(sensor, tank, z, rng, n, band=None, gap_m=(0.005, 0.012), objects=(),
                 max_draws: int | None = None) -> np.ndarray:
    """``n`` random poses of a box's tank with the sensor ``gap_m`` from two walls that meet at a corner (each gap
    drawn alone from that range; a random heading and corner), none nearer anything (an object too) than the
    first gap; at depth ``z`` or, with ``band`` (z_min, z_max), a random one. Fewer where ``max_draws`` (default
    50 n) draws leave them short (an object in every corner).

    :func:`corners_at_the_gap` puts the sensor at one gap from both walls and keeps the headings it is given;
    these fill the band between. In the tank map study's seed-4 box, 30 of them in place of the map's 30 poses
    at the gap took its error at 8 other random poses 5-12 mm from two walls from 0.102 % / 0.370 % to 0.056 % /
    0.174 % (RMS / max), 40 beside them to 0.040 % / 0.118 %; in seed 21's, 40 beside them 0.069 % / 0.162 % ->
    0.041 % / 0.092 %; without either kind, 0.130 % / 0.449 % and 0.138 % / 0.303 %.

    >>> from electrosense.meshes import preset
    >>> from electrosense.meshes.tank import Tank
    >>> sensor, tank = preset("angels-4"), Tank((1.0, 1.0, 1.0))
    >>> P = corner_poses(sensor, tank, 0.0, np.random.default_rng(0), 3)
    >>> G = np.sort(boundary_gaps_m(sensor, tank, P), axis=1)[:, :2]
    >>> bool(np.all((G >= 0.005 - 1e-9) & (G <= 0.012 + 1e-9)))
    True
    """
    column = {name: k for k, name in enumerate(tank.region_names)}
    out, draws = [], 0
    max_draws = 50 * n if max_draws is None else max_draws
    while len(out) < n and draws < max_draws:
        draws += 1
        zz = z if band is None else rng.uniform(*band)
        p = np.array([0.0, 0.0, zz, rng.uniform(-np.pi, np.pi)])
        g = boundary_gaps_m(sensor, tank, p[None])[0]
        sx, sy = rng.choice([-1.0, 1.0], 2)
        ix, iy = column["wall_x+" if sx > 0 else "wall_x-"], column["wall_y+" if sy > 0 else "wall_y-"]
        gx, gy = rng.uniform(*gap_m, 2)
        p[0], p[1] = sx * (g[ix] - gx), sy * (g[iy] - gy)     # a flat wall's gap is linear in x or y
        if boundary_gaps_m(sensor, tank, p[None], objects)[0].min() >= gap_m[0] - 1e-9:
            out.append(p)
    return np.array(out).reshape(-1, 4)


def _farthest_points(F: np.ndarray, k: int, start: np.ndarray | None = None) -> np.ndarray:
    """Indices of ``k`` rows of ``F`` spread by farthest-point sampling (from the rows ``start`` if given)."""
    d = np.full(len(F), np.inf)
    if start is not None and len(start):
        from scipy.spatial import cKDTree

        d = cKDTree(start).query(F)[0]
    out = []
    i = int(np.argmax(d)) if np.isfinite(d).any() else 0
    for _ in range(min(k, len(F))):
        out.append(i)
        d = np.minimum(d, np.linalg.norm(F - F[i], axis=1))
        i = int(np.argmax(d))
    return np.asarray(out, int)


def spread_round(X: np.ndarray, T: np.ndarray, error: np.ndarray, X_have: np.ndarray, T_have: np.ndarray, k: int,
                 spread_share: float, n_worst: int | None = None) -> np.ndarray:
    """Indices of the ``k`` rows of a round of BEM poses: ``1 - spread_share`` of them among the ``n_worst`` rows of
    largest estimated ``error`` (default 20 a pick), spread by farthest points in the map's coordinates ``X`` (B, d)
    from ``X_have``; the rest spread over the tank, farthest in the tips' positions ``T`` (B, 6) from ``T_have``
    and from the first picks. A build's coarse rounds (:data:`EXPLORE_SHARE`, over the candidates) and its
    reference rounds (:data:`REFERENCE_SPREAD_SHARE`, over the nodes, :func:`reference_round`) both take it: the
    error's estimate is right on average but leads to the walls, where a pose costs most.

    >>> X = np.linspace(0.0, 1.0, 11)[:, None]
    >>> error = np.r_[np.zeros(9), 1.0, 2.0]             # the estimated error largest at one end
    >>> spread_round(X, np.hstack([X] * 6), error, X[:1], np.zeros((1, 6)), 2, 0.5).tolist()
    [10, 5]
    """
    k_spread = int(round(spread_share * k))
    worst = np.argsort(error)[::-1][: 20 * (k - k_spread) if n_worst is None else n_worst]
    pick = worst[_farthest_points(X[worst], k - k_spread, X_have)]
    if k_spread:
        pick = np.r_[pick, _farthest_points(T, k_spread, np.vstack([T_have, T[pick]]))]
    return pick


def reference_round(X: np.ndarray, T: np.ndarray, error: np.ndarray, ref_index: np.ndarray, k: int,
                    spread_share: float = REFERENCE_SPREAD_SHARE) -> np.ndarray:
    """Indices of the ``k`` nodes (at most those left) a round of reference poses goes to (:func:`spread_round`
    over the nodes not in ``ref_index``, ``error`` the correction's estimated error (B,), 20 candidates a pose of
    the round): half where the correction's error is largest, half spread over the tank
    (:data:`REFERENCE_SPREAD_SHARE`).

    >>> X = np.linspace(0.0, 1.0, 11)[:, None]
    >>> error = np.r_[np.zeros(9), 1.0, 2.0]             # the correction's error largest at one end
    >>> reference_round(X, np.hstack([X] * 6), error, np.array([0]), 2).tolist()
    [10, 5]
    """
    free = np.setdiff1d(np.arange(len(X)), ref_index)
    k = min(int(k), len(free))
    return free[spread_round(X[free], T[free], error[free], X[ref_index], T[ref_index], k, spread_share, 20 * k)]


# ------------------------------------------------------------------ scene in the file
def scene_record(tank, objects=()) -> dict:
    """The tank and fixed objects as plain JSON data (:func:`scene_from_record` reads them back)."""
    from dataclasses import asdict

    if hasattr(tank, "radius_m"):
        t = {"kind": "cylinder", "radius_m": tank.radius_m, "height_m": tank.height_m,
             "water_depth_m": tank.water_depth_m, "floor_radius_m": tank.floor_radius_m}
    else:
        t = {"kind": "box", "size_m": list(tank.size_m), "water_depth_m": tank.water_depth_m}
    objs = []
    for o in objects:
        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(o).items()}
        d["conductivity_S_per_m"] = repr(float(o.conductivity_S_per_m))   # inf survives JSON as text
        objs.append({"shape": type(o).__name__.lower(), **d})
    return {"tank": t, "objects": objs}


def same_scene(tank, objects, other_tank, other_objects, tol_m: float = 1e-5) -> bool:
    """Whether two scenes are one, lengths compared to ``tol_m`` (a log's meta line keeps six digits).

    >>> from electrosense.meshes.tank import Tank
    >>> same_scene(Tank((0.6686797, 0.4, 0.3)), (), Tank((0.66868, 0.4, 0.3)), ())
    True
    """
    if tank is None or other_tank is None:
        return tank is other_tank
    return _close(scene_record(tank, objects), scene_record(other_tank, other_objects), tol_m)


def log_in_map_scene(tank_map, obs):
    """``obs`` (:class:`~electrosense.validation.diagnosis.observations.Observations`) in the map's scene, or a
    ValueError that names what differs: the sensor, the tank, or the fixed objects. A log that lists no objects
    (a bench logger knows the tank, not what stands in it) takes the map's; one that lists them must list the
    map's (``esense sweep`` of a scene writes them)."""
    from dataclasses import replace

    if tank_map.sensor.to_dict() != obs.sensor.to_dict():
        raise ValueError(f"the map is of sensor {tank_map.sensor.name!r}, the log of {obs.sensor.name!r}: build a map "
                         "of the log's sensor")
    if not same_scene(tank_map.tank, (), obs.tank, ()):
        raise ValueError(f"the map is of the tank {scene_record(tank_map.tank)['tank']}, the log's is "
                         f"{None if obs.tank is None else scene_record(obs.tank)['tank']}")
    if not obs.objects:
        return replace(obs, objects=tuple(tank_map.objects))
    if not same_scene(tank_map.tank, tank_map.objects, obs.tank, tuple(obs.objects)):
        raise ValueError(f"the map's fixed objects are {scene_record(tank_map.tank, tank_map.objects)['objects']}, "
                         f"the log lists {scene_record(obs.tank, tuple(obs.objects))['objects']}")
    return obs


def _close(a, b, tol: float) -> bool:
    """Equal records, numbers to ``tol``."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(u, v, tol) for u, v in zip(a, b))
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        return abs(a - b) <= tol
    return a == b


def scene_from_record(record: dict):
    """(tank, objects) from :func:`scene_record`'s data."""
    from electrosense.meshes.cylinder_tank import CylinderTank
    from electrosense.meshes.objects import Box, Cylinder, Sphere
    from electrosense.meshes.tank import Tank

    t = dict(record["tank"])
    kind = t.pop("kind")
    tank = CylinderTank(**t) if kind == "cylinder" else Tank(tuple(t["size_m"]), t["water_depth_m"])
    shapes = {"sphere": Sphere, "box": Box, "cylinder": Cylinder}
    objects = []
    for o in record.get("objects", []):
        o = dict(o)
        cls = shapes[o.pop("shape")]
        o["conductivity_S_per_m"] = float(o["conductivity_S_per_m"])
        objects.append(cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in o.items()}))
    return tank, tuple(objects)


# ------------------------------------------------------------------ the map
@dataclass
class TankMap:
    """The BEM's conductance over pose in one scene at unit conductivity, interpolated (module doc).

    ``z_m``: the depth (m) of the map, or ``(z_min, z_max)`` for a band.
    """

    sensor: object
    tank: object
    z_m: object
    nodes: np.ndarray  # (B, 4) poses where the BEM was solved
    K_nodes: np.ndarray  # (B, n, n) the BEM there, 1 S/m (on the coarse sensor mesh when coarse_factor > 1)
    K_free: np.ndarray  # (n, n) unbounded water, 1 S/m
    objects: tuple = ()
    bem_options: dict = field(default_factory=dict)  # the reference BEM's (the one the map reproduces)
    code: str = ""
    wall_gap_m: float = 0.005
    history: list = field(default_factory=list)
    sigma_S_per_m: float | None = None  # the water's conductivity the map was built for (K is kept at 1 S/m)
    warp_m: float = DEFAULT_WARP_M
    fitted: dict | None = None  # the interpolants, as stored (else fitted from the nodes)
    coarse_factor: float = 1.0  # the coarse sensor mesh's edge over the reference's (1: every node on the reference)
    ref_index: np.ndarray | None = None  # (F,) the nodes also solved on the reference mesh
    K_ref: np.ndarray | None = None  # (F, n, n) the reference BEM there, 1 S/m
    focus_m: np.ndarray | None = None  # (k, 3) the points the BEM's one tank mesh was graded towards (maps before
    # the BEM's edge bound near the sensor); None: each pose on a tank mesh graded to it alone
    reference_images_m: float | None = None  # the tank's flat faces within this distance (m) of the sensor were
    # image planes at the reference poses (:func:`image_faces_near`): the BEM the map reproduces; None: every face
    # meshed (maps before format 10)

    def __post_init__(self):
        n = self.K_free.shape[0]
        self.objects = tuple(self.objects)
        self._iu = np.triu_indices(n, 1)
        e = self.sensor.emitter - 1
        pairs = list(zip(*self._iu))
        self._rec = [pairs.index((min(k, e), max(k, e))) for k in range(n) if k != e]
        self.frame = MapFrame(self.sensor, self.tank, self.objects, self.band, self.warp_m)
        perm = self.sensor.lateral_mirror() if self.frame.mirrors else None
        # the sensor's lateral mirror where the fold reflects poses (None: nothing to permute)
        self._perm = None if perm is None or np.array_equal(perm, np.arange(len(perm))) else perm
        # one value per pair: the emitter's column of the BEM's K (what the bench reads), not its row; where the
        # fold's mirror moves the emitter (a sector emitter), a reflected node's column is another electrode's,
        # and every pair is the mean of the BEM's two estimates
        moved = self._perm is not None and self._perm[e] != e
        self._pair_emitter = None if moved else self.sensor.emitter
        self._free_pairs = pair_values(self.K_free, self._pair_emitter)
        self.ref_index = np.zeros(0, int) if self.ref_index is None else np.asarray(self.ref_index, int)
        self.K_ref = np.zeros((0, n, n)) if self.K_ref is None else np.asarray(self.K_ref, float)
        from electrosense.validation.diagnosis.anchored import RBFInterpolant

        if self.fitted is None:
            X = self.frame.features(self.nodes)
            K_nodes = self.mirrored(self.K_nodes, self.nodes)   # every node's K in its folded pose's frame
            # with the nodes' mirror images across the fold's faces (MapFrame.mirror_ghosts)
            Xg, src, odd = self.frame.mirror_ghosts(X, GHOST_REACH)
            L_coarse = np.log(pair_values(self._permuted(K_nodes, src, odd), self._pair_emitter) / self._free_pairs)
            # a node and its images are one datum, left out together (RBFInterpolant's groups): left in, an
            # image predicted its node from itself, and a node near a face of the fold seemed known
            interp = self._fit_coarse(np.vstack([X, Xg]), L_coarse, np.vstack([self.nodes, self.nodes[src]]),
                                      np.r_[np.arange(len(X)), src])
            self.fitted = {"X": np.vstack([X, Xg]), "coef": interp.coef, "loo": interp.leave_one_out,
                           "images": np.array(interp.n_regressors // max(self.frame.n_wall_images, 1))}
            if len(self.ref_index):
                Xr, corr, pairs, warp = self._fit_correction_warped(K_nodes[self.ref_index])
                self.fitted.update({"X_ref": Xr, "coef_ref": corr.coef, "loo_ref": corr.leave_one_out,
                                    "regressors_ref": pairs, "warp_ref": np.array(warp)})
        self.warp_ref_m = float(self.fitted.get("warp_ref", self.warp_m))   # the correction's (format 11: the map's)
        self.frame_ref = (self.frame if self.warp_ref_m == self.warp_m
                          else MapFrame(self.sensor, self.tank, self.objects, self.band, self.warp_ref_m))
        self._images = int(self.fitted.get("images", 0))   # the powers of the images (0: none; True: 1)
        self._parts = [RBFInterpolant.from_coefficients(self.fitted["X"], self.fitted["coef"],
                                                        self.frame.n_wall_images * self._images)]
        self._regressor_pairs = np.asarray(self.fitted.get("regressors_ref", np.zeros(0, int)), int)
        if "X_ref" in self.fitted:
            self._parts.append(RBFInterpolant.from_coefficients(self.fitted["X_ref"], self.fitted["coef_ref"],
                                                                len(self._regressor_pairs)))

    def _receiver_rms(self, interpolant) -> float:
        """RMS over the nodes and the emitter's pairs of an interpolant's leave-one-out errors."""
        return float(np.sqrt(np.mean(np.asarray(interpolant.leave_one_out)[:, self._rec] ** 2)))

    def _permuted(self, K: np.ndarray, source: np.ndarray, odd: np.ndarray) -> np.ndarray:
        """K (B, n, n) followed by the K of its mirror images ``K[source]``, the electrodes permuted by the sensor's
        lateral mirror where the image is reflected (``odd``; :meth:`MapFrame.mirror_ghosts`)."""
        ghosts = np.array(K[source], float)
        if self._perm is not None and odd.any():
            ghosts[odd] = ghosts[odd][..., self._perm, :][..., :, self._perm]
        return np.concatenate([K, ghosts])

    def _fit_coarse(self, X, L_coarse, poses, groups=None):
        """log(K_coarse / K_free) (B, pairs) at ``poses`` (B, 4; a mirror image's at its node's, whose images in
        the walls are its own) interpolated over the features ``X``: radial basis functions with a
        quadratic trend (:data:`RBF_DEGREE`), with the walls' images as linear regressors
        (:meth:`MapFrame.wall_images`), their first :data:`IMAGE_POWERS` powers or the first alone, or without,
        whichever is closer at left-out nodes (RMS over the receivers). In boxes the images came 1.2-2x closer at
        left-out nodes and 1.2-1.5x at fresh poses (three maps of 324-612 poses); in a cylinder, whose folded map
        has two coordinates, they did not. ``groups``: the rows left out together (a node and its mirror
        images)."""
        from electrosense.validation.diagnosis.anchored import RBFInterpolant, trend_terms

        best = RBFInterpolant(X, L_coarse, degree=RBF_DEGREE, groups=groups)
        R = self.frame.wall_images(poses)
        for powers in sorted({1, IMAGE_POWERS}):   # the first alone, then all
            if len(X) <= 2 * (trend_terms(X.shape[1], RBF_DEGREE) + powers * R.shape[1]):   # too few nodes
                break
            imaged = RBFInterpolant(X, L_coarse, degree=RBF_DEGREE, regressors=image_powers(R, powers)[0],
                                    groups=groups)
            if self._receiver_rms(imaged) < self._receiver_rms(best):
                best = imaged
        return best

    def _fit_correction_warped(self, K_at_ref):
        """The reference correction fitted at each warp of :data:`CORRECTION_WARP_FACTORS` (its features, with
        the reference nodes' mirror images, in a :class:`MapFrame` of that warp) and the one closest at left-out
        reference poses: ``(X_ref, interpolant, pairs, warp_m)``; ``K_at_ref`` the coarse K at the reference
        nodes in their folded poses' frames."""
        poses = self.nodes[self.ref_index]
        K_ref_folded = self.mirrored(self.K_ref, poses)
        best = None
        for factor in CORRECTION_WARP_FACTORS:
            warp = self.warp_m * factor
            frame = self.frame if factor == 1.0 else MapFrame(self.sensor, self.tank, self.objects, self.band, warp)
            Xr = frame.features(poses)
            Xrg, src_r, odd_r = frame.mirror_ghosts(Xr, GHOST_REACH)
            K_ref = self._permuted(K_ref_folded, src_r, odd_r)
            K_at = self._permuted(K_at_ref, src_r, odd_r)
            d = np.log(pair_values(K_ref, self._pair_emitter) / pair_values(K_at, self._pair_emitter))
            L_at = np.log(pair_values(K_at, self._pair_emitter) / self._free_pairs)
            Xr = np.vstack([Xr, Xrg])
            corr, pairs = self._fit_correction(Xr, d, L_at, np.r_[np.arange(len(self.ref_index)), src_r])
            if best is None or self._receiver_rms(corr) < self._receiver_rms(best[1]):
                best = (Xr, corr, pairs, warp)
        return best

    def _fit_correction(self, X_ref, d, L_coarse, groups=None):
        """The correction ``d`` = log(K_ref / K_coarse) (F, pairs) interpolated over the features ``X_ref``: as a
        function of the pose alone (quintic, :data:`RBF_DEGREE`), or as a linear function of the coarse log ratio
        of the emitter's pairs ``L_coarse`` (F, pairs) plus a cubic remainder (the regressors of
        :class:`RBFInterpolant`), whichever is closer at left-out reference poses (RMS over the receivers);
        returns the interpolant and the pairs it regresses on (empty: the pose alone); ``groups`` as in
        :meth:`_fit_coarse`."""
        from electrosense.validation.diagnosis.anchored import RBFInterpolant

        plain = RBFInterpolant(X_ref, d, degree=RBF_DEGREE, groups=groups)
        pairs = np.asarray(self._rec, int)
        if len(X_ref) <= X_ref.shape[1] + len(pairs) + 2:   # too few poses for the regression and a linear trend
            return plain, np.zeros(0, int)
        linked = RBFInterpolant(X_ref, d, degree=1, regressors=L_coarse[:, pairs], groups=groups)
        if self._receiver_rms(linked) < self._receiver_rms(plain):
            return linked, pairs
        return plain, np.zeros(0, int)

    def mirrored(self, K: np.ndarray, poses) -> np.ndarray:
        """K (P, ..., n, n) with the electrodes permuted by the sensor's lateral mirror at the poses whose fold
        reflects them (:meth:`MapFrame.reflected`): from a pose's frame to its folded pose's, and back (an
        involution). A copy; K itself where nothing is reflected."""
        perm = self._perm
        if perm is None:
            return K
        out = np.array(K, float, copy=True)
        r = self.frame.reflected(poses)
        out[r] = out[r][..., perm, :][..., :, perm]
        return out

    @property
    def band(self) -> bool:
        return np.ndim(self.z_m) > 0

    @property
    def z_range_m(self) -> tuple[float, float]:
        z = np.atleast_1d(np.asarray(self.z_m, float))
        return float(z.min()), float(z.max())

    @property
    def leave_one_out(self) -> np.ndarray:
        """(B, m) relative leave-one-out error of the receiver currents at the nodes (of the coarse interpolant
        when the map has a reference correction: its own is :attr:`leave_one_out_ref`)."""
        return np.abs(np.expm1(np.asarray(self.fitted["loo"])[:, self._rec]))

    @property
    def leave_one_out_ref(self) -> np.ndarray:
        """(F, m) relative leave-one-out error of the reference correction at its nodes (empty without one)."""
        if "loo_ref" not in self.fitted:
            return np.zeros((0, len(self._rec)))
        return np.abs(np.expm1(np.asarray(self.fitted["loo_ref"])[:, self._rec]))

    def log_ratio(self, poses, jacobian: bool = False, chunk: int = 4096, correction: bool = True):
        """log(K / K_free) of the upper triangle, (P, pairs); with ``jacobian`` also its d/d(x, y, yaw), (P, 3, pairs);
        without ``correction`` the coarse interpolant alone (the map's coarse BEM, :attr:`fidelities`)."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        out, dout = [], []
        for s in range(0, len(poses), chunk):
            Q = poses[s:s + chunk]
            F, dF = self.frame.features(Q, jacobian=True) if jacobian else (self.frame.features(Q), None)
            R, dR = None, None
            if self._images:
                R, dR = self.frame.wall_images(Q, jacobian=True) if jacobian else (self.frame.wall_images(Q), None)
                R, dR = image_powers(R, self._images, dR)
            coarse = self._parts[0]
            L, G = _value_and_pose_gradient(coarse, F, dF, R, dR) if jacobian else (coarse(F, R), None)
            if correction and len(self._parts) > 1:   # the reference correction (of the pose and the coarse K)
                reg = self._regressor_pairs
                corr = self._parts[1]
                Fr, dFr = ((F, dF) if self.frame_ref is self.frame else
                           self.frame_ref.features(Q, jacobian=True) if jacobian else (self.frame_ref.features(Q), None))
                if jacobian:
                    v, g = _value_and_pose_gradient(corr, Fr, dFr, L[:, reg], G[:, :, reg])
                    L, G = L + v, G + g
                else:
                    L = L + corr(Fr, L[:, reg])
            out.append(L)
            if jacobian:
                dout.append(G)
        L = np.concatenate(out) if out else np.zeros((0, len(self._iu[0])))
        return (L, np.concatenate(dout)) if jacobian else L

    def conductance(self, poses, sigma_S_per_m: float = 1.0, jacobian: bool = False, correction: bool = True):
        """K (P, n, n) at ``poses`` (P, 4), zero row sums, at ``sigma_S_per_m``; with ``jacobian`` also
        dK / d(x, y, yaw), (P, 3, n, n): one vectorised call for any number of poses. Without ``correction``: the
        coarse interpolant alone, which reproduces the map's coarse BEM (:attr:`fidelities`), not the reference."""
        n = self.K_free.shape[0]
        iu = self._iu
        res = self.log_ratio(poses, jacobian, correction=correction)
        L, dL = res if jacobian else (res, None)
        off = self._free_pairs * np.exp(L) * sigma_S_per_m
        K = self.mirrored(_assemble(off, n, iu), poses)
        if not jacobian:
            return K
        return K, self.mirrored(_assemble(off[:, None, :] * dL, n, iu), poses)

    def jacobian(self, poses, sigma_S_per_m: float = 1.0) -> np.ndarray:
        """dK / d(x, y, yaw) (P, 3, n, n) (analytic: the interpolant's derivative through the map's coordinates)."""
        return self.conductance(poses, sigma_S_per_m, jacobian=True)[1]

    @property
    def fidelities(self) -> dict:
        """The options of the map's two BEMs (:func:`bem_fidelities`; maps of format 10 and later): ``"ref"`` the
        one it reproduces, ``"coarse"`` the one its many nodes were solved with."""
        if self.focus_m is not None or (self.tank is not None and self.reference_images_m is None):
            raise ValueError("a map before format 10 was built on one tank mesh or with its reference's faces meshed: "
                             "its BEMs are not those of bem_fidelities")
        return bem_fidelities(self.tank, dict(self.bem_options), self.coarse_factor * self.bem_options["edge_length_m"])

    def estimated_error(self, poses) -> np.ndarray:
        """(P, m) estimated relative error of the receiver currents at ``poses`` (zero at the nodes): the coarse
        interpolant's and the reference correction's, in quadrature."""
        return self._error_at(poses, self.frame.features(np.asarray(poses, float)))

    def _error_at(self, poses, F) -> np.ndarray:
        """:meth:`estimated_error` at ``poses`` whose map coordinates are ``F``."""
        err = self.coarse_error_at(F)
        if len(self._parts) > 1:
            err = np.hypot(err, self.correction_error_at(poses, F))
        return np.take_along_axis(err, self._folded_receivers(poses), axis=1)

    def coarse_error_at(self, F) -> np.ndarray:
        """(P, receivers) the coarse interpolant's estimated error at map coordinates ``F`` (folded poses' receivers),
        from its nodes' left-out errors (:func:`~electrosense.validation.diagnosis.anchored.estimated_error`)."""
        from electrosense.validation.diagnosis.anchored import estimated_error

        return estimated_error(self._parts[0].X, self.leave_one_out, F)

    def correction_error_at(self, poses, F=None) -> np.ndarray:
        """(P, receivers) the reference correction's estimated error at ``poses`` (``F`` their coarse map coordinates,
        taken where the correction shares them), from its left-out errors in its own coordinates."""
        from electrosense.validation.diagnosis.anchored import estimated_error

        poses = np.asarray(poses, float).reshape(-1, 4)
        Fr = F if F is not None and self.frame_ref is self.frame else self.frame_ref.features(poses)
        return estimated_error(self._parts[1].X, self.leave_one_out_ref, Fr)

    def _folded_receivers(self, poses) -> np.ndarray:
        """(P, m) each pose's receivers as columns of its folded pose's (a reflected pose's are permuted)."""
        m = len(self._rec)
        folded = np.tile(np.arange(m), (len(np.reshape(poses, (-1, 4))), 1))
        perm, e = self._perm, self.sensor.emitter - 1
        if perm is not None and perm[e] == e:
            receivers = [k for k in range(len(perm)) if k != e]
            folded[self.frame.reflected(poses)] = [receivers.index(perm[k]) for k in receivers]
        return folded

    def error_covariance(self, poses) -> np.ndarray:
        """(P m, P m) covariance of the relative errors of the receiver currents at ``poses``, in the order of a
        (P, m) array's ``ravel()``. Its standard deviations are :meth:`estimated_error`'s; an interpolation error is
        smooth, so two poses between the same nodes share it: the correlation along the poses is a Matern 3/2
        function of their distance in the map's coordinates, whose length is the spacing of the nodes nearest to
        them (the median distance from each to its nearest other node), and across receivers that of the (coarse)
        nodes' leave-one-out errors. An
        object's signal is smooth along a pass too: a detector that took the map's error as independent from
        pose to pose would call the map's error an object (:func:`~electrosense.validation.localisation.
        object_position.locate_object`).
        """
        from scipy.spatial import cKDTree
        from scipy.spatial.distance import cdist

        poses = np.asarray(poses, float).reshape(-1, 4)
        F = self.frame.features(poses)
        sd = self._error_at(poses, F)
        X = self._parts[0].X
        tree = cKDTree(X)
        spacing = tree.query(X, k=2)[0][:, 1] if len(X) > 1 else np.ones(1)
        length = float(np.median(spacing[tree.query(F)[1]]))
        r = np.sqrt(3.0) * cdist(F, F) / max(length, 1e-12)
        R = (1.0 + r) * np.exp(-r)      # Matern 3/2: smooth, yet not so smooth that whitening trusts its curvature
        loo = np.expm1(np.asarray(self.fitted["loo"])[:, self._rec])
        with np.errstate(invalid="ignore", divide="ignore"):
            Q = np.atleast_2d(np.corrcoef(loo.T)) if len(loo) > 2 else np.eye(loo.shape[1])
        Q = np.where(np.isfinite(Q), Q, np.eye(len(Q)))
        m = sd.shape[1]
        i = self._folded_receivers(poses).ravel()
        s = sd.ravel()
        return np.repeat(np.repeat(R, m, axis=0), m, axis=1) * Q[np.ix_(i, i)] * np.outer(s, s)

    def covers(self, poses) -> tuple[np.ndarray, str]:
        """(P,) bool: poses inside the map (its depth or band, its wall gap), and why the first other is not."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        z0, z1 = self.z_range_m
        off_z = (poses[:, 2] < z0 - 1e-6) | (poses[:, 2] > z1 + 1e-6)
        gap = sensor_wall_gap_m(self.sensor, self.tank, poses, self.objects)
        close = gap < self.wall_gap_m - 1e-6
        why = ""
        if off_z.any():
            i = int(np.argmax(off_z))
            where = f"z = {z0:g} m" if z1 == z0 else f"z = {z0:g} to {z1:g} m"
            why = f"pose {i} is at z = {poses[i, 2]:g} m; the map is at {where}"
        elif close.any():
            i = int(np.argmax(close))
            where = (f"{-1e3 * gap[i]:.1f} mm beyond a wall or into an object" if gap[i] < 0
                     else f"{1e3 * gap[i]:.1f} mm from a wall or object")
            why = (f"pose {i} (x {poses[i, 0]:g} m, y {poses[i, 1]:g} m, heading {poses[i, 3]:g} rad) puts the "
                   f"sensor {where}; the map reaches {1e3 * self.wall_gap_m:g} mm"
                   + (f" ({int(close.sum())} of {len(poses)} poses)" if close.sum() > 1 else ""))
        return ~(off_z | close), why

    # ------------------------------------------------------------------ file
    def meta(self) -> dict:
        return {"format": MAP_FORMAT, "sensor": self.sensor.to_dict(), **scene_record(self.tank, self.objects),
                "z_m": (list(self.z_range_m) if self.band else float(self.z_m)), "wall_gap_m": self.wall_gap_m,
                "warp_m": self.warp_m, "coarse_factor": self.coarse_factor,
                "bem_options": {k: v for k, v in self.bem_options.items() if isinstance(v, (int, float, str))},
                "code": self.code, "history": self.history, "sigma_S_per_m": self.sigma_S_per_m,
                "reference_images_m": self.reference_images_m}

    def save(self, path) -> Path:
        """One ``.npz``: arrays, and the scene, sensor, options and code version as JSON (written atomically)."""
        path = Path(path)
        partial = path.with_name(f"{path.name}.{os.getpid()}.writing.npz")
        ref = {k: self.fitted[k] for k in REFERENCE_KEYS if k in self.fitted}
        np.savez(partial, nodes=self.nodes, K_nodes=self.K_nodes, K_free=self.K_free, X=self.fitted["X"],
                 coef=self.fitted["coef"], loo=self.fitted["loo"], images=self.fitted.get("images", False),
                 ref_index=self.ref_index, K_ref=self.K_ref,
                 focus_m=np.zeros((0, 3)) if self.focus_m is None else self.focus_m,
                 meta=json.dumps(self.meta()), **ref)
        partial.replace(path)
        return path


def image_powers(R: np.ndarray, powers: int, dR: np.ndarray | None = None):
    """The walls' images ``R`` (P, r) and their powers up to ``powers``, (P, powers * r), and with their pose
    gradient ``dR`` (P, 3, r) given, theirs, (P, 3, powers * r) (else None).

    >>> R, dR = image_powers(np.array([[2.0, 3.0]]), 2, np.ones((1, 3, 2)))
    >>> R.tolist(), dR[0, 0].tolist()
    ([[2.0, 3.0, 4.0, 9.0]], [1.0, 1.0, 4.0, 6.0])
    """
    out = np.concatenate([R ** k for k in range(1, powers + 1)], axis=-1)
    if dR is None:
        return out, None
    return out, np.concatenate([k * R[:, None, :] ** (k - 1) * dR for k in range(1, powers + 1)], axis=-1)


def _value_and_pose_gradient(interpolant, F, dF, R=None, dR=None):
    """An interpolant's values (P, k) at the features ``F`` (P, d) and their gradient by the pose (P, 3, k),
    through the features' ``dF`` (P, d, 3) and its regressors' values ``R`` (P, r) and pose gradient ``dR``
    (P, 3, r), where it has regressors."""
    r = interpolant.n_regressors
    v, G = interpolant.value_and_gradient(F, R, np.zeros(F.shape + (r,)) if r else None)
    G = np.einsum("pkq,pkj->pjq", G, dF)
    if r:
        G = G + np.einsum("pjr,rq->pjq", dR, interpolant.regressor_coefficients)
    return v, G


def _assemble(off: np.ndarray, n: int, iu) -> np.ndarray:
    """Symmetric (..., n, n) with zero row sums from its strict upper triangle (..., pairs)."""
    K = np.zeros(off.shape[:-1] + (n, n))
    K[..., iu[0], iu[1]] = off
    K = K + np.swapaxes(K, -1, -2)
    K[..., np.arange(n), np.arange(n)] = -K.sum(axis=-1)
    return K


def load_tank_map(path) -> TankMap:
    """A :class:`TankMap` from its file (reads arrays: no fit); refuses another format with a clear error."""
    from electrosense.meshes.sensor import SensorDescription

    path = Path(path)
    if path.is_file() and not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a tank map (not an .npz archive, as `esense map build` writes)")
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in ("nodes", "K_nodes", "K_free", "X", "coef", "loo", "images", "ref_index",
                                        "K_ref", "focus_m")}
            arrays.update({k: z[k] for k in REFERENCE_KEYS if k in z.files})
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:   # a truncated or foreign archive
        raise ValueError(f"{path}: not a tank map ({type(exc).__name__}: {exc})") from None
    if meta.get("format") not in READABLE_FORMATS:
        raise ValueError(f"{path}: not a tank map of this version (format {meta.get('format')!r}, expected "
                         f"{MAP_FORMAT!r}); build it again")
    try:
        tank, objects = scene_from_record(meta)
        sensor = SensorDescription.from_dict(meta["sensor"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: the map's scene cannot be read ({exc})") from None
    z = meta["z_m"]
    fitted = {k: arrays[k] for k in ("X", "coef", "loo", "images", *REFERENCE_KEYS) if k in arrays}
    if meta["format"] == "electrosense tank map 8" and objects:   # fitted without the objects' images: again
        fitted = None
    return TankMap(sensor, tank, tuple(z) if isinstance(z, list) else float(z), arrays["nodes"], arrays["K_nodes"],
                   arrays["K_free"], objects, meta.get("bem_options", {}), meta.get("code", ""),
                   float(meta.get("wall_gap_m", 0.005)), meta.get("history", []), meta.get("sigma_S_per_m"),
                   float(meta.get("warp_m", DEFAULT_WARP_M)),
                   fitted, float(meta.get("coarse_factor", 1.0)), arrays["ref_index"], arrays["K_ref"],
                   arrays["focus_m"] if len(arrays["focus_m"]) else None, meta.get("reference_images_m"))


# ------------------------------------------------------------------ build
_WORKER = {}


def _refine_pays(rms_coarse: float, n_coarse: int, cpu_coarse_s: float | None, rms_ref: float, n_ref: int,
                 cpu_ref_s: float | None) -> bool:
    """Whether a round of reference poses removes more of the map's squared error per CPU second than a round of
    coarse ones.

    The interpolation's error and the correction's add in quadrature, and each falls about as a power of its own
    number of poses, ``rms ~ n^-a``: a pose more removes about ``2 a rms^2 / n`` of the squared error, the same
    ``a`` for both (measured: the coarse interpolation's about n^-1.45; the correction of a random 5-electrode
    sensor's map, at 48 fresh poses, 0.0147 % RMS with 12 reference poses, 0.0065 % with 24). So the
    correction is refined where ``rms_ref^2 / (n_ref cpu_ref)`` is the larger, even while its error is the
    smaller: that map's correction, 12 poses at 2-3 s against 372 coarse ones at 1.1 s, erred as much as its
    interpolation at fresh poses (0.015 % and 0.014 %) for 6 % of the CPU. A cost not yet measured is taken as
    the other's.

    >>> _refine_pays(0.03e-2, 372, 1.1, 0.015e-2, 12, 2.5), _refine_pays(0.8e-2, 60, 1.1, 0.015e-2, 12, 2.5)
    (True, False)
    """
    cpu_coarse_s = cpu_coarse_s or cpu_ref_s or 1.0
    cpu_ref_s = cpu_ref_s or cpu_coarse_s
    if n_ref == 0:
        return True
    return rms_ref**2 / (n_ref * cpu_ref_s) > rms_coarse**2 / (max(n_coarse, 1) * cpu_coarse_s)


#: the coarse sensor mesh's edge over the reference's, for the many poses of a map (the reference mesh, 3.5x the
#: CPU per pose, at fewer poses corrects them): 3 is the diagnosis anchors' factor
COARSE_FACTOR = 3.0

#: the relative truncation of the sensor-tank coupling in the map's BEM poses (:class:`~electrosense.bem.PoseSweep`'s
#: ``tol``; the BEM's own default 1e-6): the poses the map crowds near the walls carry ranks of 170-590 at 1e-6 and
#: 110-370 at 1e-5, and a pose costs 25 % less (a random 5-electrode sensor in a 0.77 x 0.52 m box, tips 5-14 mm
#: from a wall: 3.6 s against 4.9 s of CPU) for K within 6e-6 of the untruncated coupling at the worst of four
#: (1e-6: 1e-6; 3e-5: 5e-5), 4 % of the map's RMS target. The map's checks solve at the BEM's default.
MAP_COUPLING_TOL = 1e-5

#: the tank mesh's growth of edge per metre from the sensor for the map's reference BEM (the coarse poses keep the
#: BEM's default, :data:`~electrosense.meshes.scene_mesh.DEFAULT_TANK_GRADING`, 0.25). The default's graded panels
#: leave K 0.034 % RMS (0.073 % max) from a tank mesh graded at 0.1 (6 300 triangles) in the tank map study's
#: seed-4 box (0.77 x 0.52 m, six random poses, the receivers' currents), twice the map's goal; at 0.15, 0.013 %
#: (0.030 %) for 1.8x the tank's triangles, 1.36x a reference pose's CPU (its sensor block dominates); seed 2's
#: box 0.014 % -> 0.005 %. A ladder of gradings 0.25 / 0.18 / 0.13 / 0.09 against 0.065 at two poses:
#: 0.032 / 0.016 / 0.011 / 0.004 %. Limiting the far edge instead (a sixth or an eighth of the smaller side)
#: took 0.038 % to 0.030 / 0.028 %: the error is the graded middle distance's, not the farthest panels'.
REFERENCE_TANK_GRADING = 0.15

#: the tank's edge near the sensor at most this times its distance from the sensor on the many coarse poses (the
#: reference keeps the BEM's :data:`~electrosense.meshes.scene_mesh.DEFAULT_TANK_NEAR_RATIO`, 0.35). A pose near a
#: wall is the tank mesh's cost: angels-4 on the coarse sensor mesh, 3 degrees off parallel to the 1 m tank's wall,
#: 5 / 7.5 / 11 mm from it, costs 17.4 / 5.5 / 3.1 s of CPU at 0.35 (6 800 tank triangles at 5 mm, 680 mid-tank),
#: 3.7 / 2.1 / 1.3 s at 0.7, for K 0.10 / 0.10 / 0.08 % from a mesh at 0.25 (0.35: 0.017 %): an error of the
#: wall's effect, smooth in the pose, which the correction to the reference (linear in the coarse K) takes out.
#: Measured on whole builds (the same budget): the seed-4 study's map 305 -> 380 BEM poses, 0.020 -> 0.019 % RMS,
#: 0.087 -> 0.071 % max at its 20 test poses and 0.149 -> 0.119 % RMS, 0.40 -> 0.34 % max at its 8 near-wall ones;
#: angels-4 in the 1 m tank at 80 fresh poses (20 within 15 mm of a wall) 0.049 -> 0.037 % RMS, 0.36 -> 0.26 % max.
COARSE_TANK_NEAR_RATIO = 0.7


def estimate_checked(tank_map, poses: np.ndarray, K_bem: np.ndarray, fidelity: str) -> dict:
    """A map's estimated error checked at the poses of its next round, before they join it: the RMS over those
    poses and the emitter's receivers (:func:`~electrosense.bem.conductance.pair_values`, as the map keeps them)
    of the relative error of its ``fidelity``'s part ("coarse": the coarse
    interpolant against the coarse BEM ``K_bem`` (P, n, n); "ref": the corrected map at coarse nodes against the
    reference BEM there, the correction's error alone, since the coarse interpolant is exact at its nodes) and
    of that part's estimate (:meth:`TankMap.estimated_error`'s coarse term, or :meth:`TankMap.correction_error_at`).

    Held-out data the build gets for free: each round's poses are solved anyway. They are not a random sample: a
    round goes mostly where the estimate is largest (:func:`spread_round`), so a ratio below 1 there says the
    estimate's maxima are high, not that it is high everywhere (the study's random poses near the walls are the
    unbiased check). ``{"fidelity", "poses", "rms_error", "estimated_rms_error"}``.
    """
    if fidelity == "coarse":
        K_map = tank_map.conductance(poses, correction=False)
        est = tank_map.coarse_error_at(tank_map.frame.features(poses))
    else:
        K_map = tank_map.conductance(poses)
        est = tank_map.correction_error_at(poses)
    # the map's own values: a pair with the emitter from its column (pair_values), the emitter's receivers
    rec, emitter = tank_map._rec, tank_map._pair_emitter
    actual = pair_values(K_map, emitter)[:, rec] / pair_values(np.asarray(K_bem, float), emitter)[:, rec] - 1.0
    return {"fidelity": fidelity, "poses": int(len(poses)), "rms_error": float(np.sqrt(np.mean(actual**2))),
            "estimated_rms_error": float(np.sqrt(np.mean(np.asarray(est) ** 2)))}


def estimate_ratios(history: list) -> dict:
    """``{fidelity: (rounds, ratio)}``: over a build's rounds (:func:`estimate_checked` in their ``next_round``),
    the RMS of the actual errors at each round's poses over the RMS of their estimates, pooled by fidelity (empty
    for a map built before the check).

    >>> estimate_ratios([{"next_round": {"fidelity": "coarse", "poses": 4, "rms_error": 0.001,
    ...                                  "estimated_rms_error": 0.002}}, {}])
    {'coarse': (1, 0.5)}
    """
    pooled = {}
    for h in history:
        r = h.get("next_round")
        if r:
            n, a, b = pooled.get(r["fidelity"], (0, 0.0, 0.0))
            pooled[r["fidelity"]] = (n + 1, a + r["poses"] * r["rms_error"] ** 2,
                                     b + r["poses"] * r["estimated_rms_error"] ** 2)
    return {f: (n, float(np.sqrt(a / b)) if b > 0 else float("inf")) for f, (n, a, b) in pooled.items()}


def bem_fidelities(tank, options: dict, coarse_edge_m: float) -> dict:
    """The options of a map's two BEMs, ``{"ref": ..., "coarse": ...}``, from the reference's ``options`` (its
    ``edge_length_m`` and ``tank_grading`` set) and the coarse sensor mesh's edge ``coarse_edge_m``: the many
    poses on the BEM's default tank mesh (or the reference's, where that is the coarser) with its edge near the
    sensor at :data:`COARSE_TANK_NEAR_RATIO`; both with the sensor-tank coupling truncated at
    :data:`MAP_COUPLING_TOL` and the tank's flat faces within :data:`IMAGE_FACES_WITHIN_M` of the sensor image
    planes (``image_faces_within_m``; exact, where a meshed wall beside the sensor converges slowly).

    >>> from electrosense.meshes import Tank
    >>> f = bem_fidelities(Tank((1.0, 1.0, 1.0)), {"edge_length_m": 0.004, "tank_grading": 0.15}, 0.012)
    >>> f["coarse"]["edge_length_m"], f["coarse"]["tank_grading"], f["ref"]["image_faces_within_m"]
    (0.012, 0.25, 0.08)
    """
    from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING

    tol = {"tol": MAP_COUPLING_TOL}
    if tank is None:
        return {"ref": {**options, **tol}, "coarse": {**options, **tol, "edge_length_m": coarse_edge_m}}
    images = {"image_faces_within_m": IMAGE_FACES_WITHIN_M}
    return {"ref": {**options, **tol, **images},
            "coarse": {**options, **tol, **images, "edge_length_m": coarse_edge_m,
                       "tank_grading": max(options["tank_grading"], DEFAULT_TANK_GRADING),
                       "tank_near_ratio": COARSE_TANK_NEAR_RATIO}}


def _worker_init(sensor, tank, objects, options, memory_share=1.0):
    _WORKER.update(args=(sensor, tank, objects), options=options, sweeps={}, memory_share=memory_share)


def _pool_worker_init(*args):
    """:func:`_worker_init` in a worker process, which ends itself when the build that started it is gone and
    computes on one thread (:func:`one_thread`)."""
    exit_with_parent()
    one_thread()
    _worker_init(*args)


def _worker_sweep(fidelity: str):
    """This process's :class:`~electrosense.bem.PoseSweep` on the ``fidelity``'s sensor mesh, set up on first use
    (a map without a correction never pays for the reference), and the distance within which its poses take the
    tank's flat faces as image planes (None: never; the options' ``image_faces_within_m``); its sensor block goes
    to the disk cache, where the other workers find it."""
    from electrosense.bem import PoseSweep

    if fidelity not in _WORKER["sweeps"]:
        sensor, tank, objects = _WORKER["args"]
        options = dict(_WORKER["options"][fidelity])
        within_m = options.pop("image_faces_within_m", None)
        _WORKER["sweeps"][fidelity] = PoseSweep(sensor, tank, objects, sigma_S_per_m=1.0,
                                                memory_share=_WORKER["memory_share"], **options), within_m
    return _WORKER["sweeps"][fidelity]


def _worker_prepare(fidelity: str):
    """Set up this process's sweep of ``fidelity`` ahead of its poses; this process's id and CPU seconds."""
    _worker_sweep(fidelity)
    return os.getpid(), time.process_time()


def _worker_solve(poses, fidelity: str = "coarse"):
    """K at ``poses`` on the ``fidelity``'s sensor mesh ("coarse" or "ref"), each pose on a tank mesh graded to it
    alone (:meth:`~electrosense.bem.PoseSweep.with_focus`, the sensor's block shared), this process's id and its
    CPU seconds so far (its set-up included)."""
    sweep, within_m = _worker_sweep(fidelity)
    if sweep.tank is None and not sweep.objects:
        return sweep.conductance(poses).K_S, os.getpid(), time.process_time()
    return each_on_its_own_tank_mesh(sweep, poses, within_m), os.getpid(), time.process_time()


def each_on_its_own_tank_mesh(sweep, poses, image_faces_within_m: float | None = None) -> np.ndarray:
    """K (P, n, n) of a :class:`~electrosense.bem.PoseSweep` at ``poses`` (P, 4), each on a tank mesh graded to
    it alone (:meth:`~electrosense.bem.PoseSweep.with_focus`, the sensor's block shared), the tank's flat faces
    within ``image_faces_within_m`` of the sensor image planes (:func:`image_faces_near`; None: every face
    meshed): as a map's nodes."""
    if image_faces_within_m is None or sweep.tank is None:
        faces = [()] * len(poses)
    else:
        faces = image_faces_near(sweep.sensor, sweep.tank, poses, image_faces_within_m)
    return np.concatenate([sweep.with_focus(tank_near_ratio=sweep.tank_near_ratio, image_face=f or None)
                           .conductance(pose[None]).K_S for pose, f in zip(poses, faces)])


#: a flat face of the tank within this distance (m) of the sensor's surface is an image plane at a map's coarse
#: BEM poses (:func:`image_faces_near`). The coarse poses' tank mesh against the image (angels-4 3 degrees off
#: parallel to the 1 m tank's wall, the coarse sensor mesh, COARSE_TANK_NEAR_RATIO): 0.108 / 0.040 / 0.016 / 0.010
#: / 0.007 / 0.0065 % at 5 / 20 / 40 / 60 / 80 / 100 mm, so a face that enters the images as the pose moves makes
#: a step of about 0.007 % in the coarse K, which a larger distance would hardly lower (the mesh's far error)
IMAGE_FACES_WITHIN_M = 0.08


def image_faces_near(sensor, tank, poses: np.ndarray, within_m: float = IMAGE_FACES_WITHIN_M) -> list:
    """The tank's flat faces within ``within_m`` of the sensor's surface at each of ``poses`` (P, 4), at most one
    of each pair of opposite faces (the nearer): a tuple of names per pose, empty where none is that near.

    A map's BEM poses take them as image planes (:mod:`electrosense.bem.image_plane`; mutually perpendicular: a
    box's wall, the next wall and the floor at a corner), the coarse and, since format 10, the reference poses.
    On the coarse sensor mesh an image costs no more than the face's mesh (the sensor's own image is what makes it
    dear, and the coarse sensor is small), and it takes the tank mesh's error, largest next to the sensor and
    steepest in the pose, out of the K the many poses interpolate. At the reference poses the image is the
    converged wall: a random 4-electrode sensor's reference (seed 21) at 4 poses 5-15 mm from a wall, its
    meshed walls 0.034-0.065 % from the images at the reference grading (0.15) and still 0.015-0.045 % at 0.06,
    where the images move by 0.005 % RMS between gradings 0.15 and 0.09 and by 0.013-0.016 % with a 0.7x finer
    sensor mesh (the sensor's own error, as mid-tank). Every face that near, not only the nearest (the nearest
    alone switched from wall to wall across a corner, and the other's mesh error made a step).

    >>> from electrosense.meshes import Tank, preset
    >>> image_faces_near(preset("angels-4"), Tank((1.0, 1.0, 1.0)), np.array([[0.2, 0.45, 0.0, 0.0], [0, 0, 0, 0]]))
    [('wall_y+',), ()]
    """
    gap = tank.distance_to_boundary_m(_axis_points(sensor, poses)).min(axis=1) - sensor.radius_m   # (P, regions)
    column = {name: k for k, name in enumerate(tank.region_names)}
    out = []
    for g in gap:
        faces = []
        for a, b in tank.flat_region_pairs:
            nearer = a if g[column[a]] <= g[column[b]] else b
            if g[column[nearer]] < within_m:
                faces.append(nearer)
        out.append(tuple(faces))
    return out


def check_pose_memory(sensor, tank, objects, options: dict, poses: np.ndarray, memory_share: float) -> None:
    """Refuse (:class:`~electrosense.bem.memory.MemoryRefusal`), before any BEM, what a worker's sweeps could not
    hold: ``poses`` (those nearest a wall: the finest tank mesh) on each of ``options``' sensor meshes, all of a
    worker's sweeps at their largest at once (a worker keeps a sweep of each mesh; it solves one pose at a time,
    so this is an upper bound) within ``memory_share`` of the memory. Cheap: the sensor meshes are counted, not
    made, and a tank mesh is made once per pose for every mesh that shares its options.

    The sum, not a share per sweep: a random 5-electrode sensor of 12 354 reference triangles, whose reference
    pose beside a wall needs 5.1 GB, was refused on a 24.5 GB machine with two workers when each of a worker's two
    sweeps was given a quarter of the memory (4.9 GB), though the two together need at most 7.2 GB of the worker's 9.8."""
    from electrosense.bem.memory import check_bytes, dense_system_bytes
    from electrosense.bem.sweep import pose_bytes
    from electrosense.meshes.object_mesh import mesh_object
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.scene_mesh import (
        DEFAULT_TANK_GRADING,
        DEFAULT_TANK_NEAR_RATIO,
        mesh_tank_around,
        sensor_axis_points_m,
    )
    from electrosense.meshes.sensor_mesh import estimate_triangles

    n_objects = sum(mesh_object(o, None).n_triangles for o in objects)
    n_tank, needs = {}, []
    for name, opts in options.items():
        how = (opts.get("tank_edge_length_m"), opts.get("tank_grading") or DEFAULT_TANK_GRADING,
               opts.get("tank_near_ratio", DEFAULT_TANK_NEAR_RATIO))
        if how not in n_tank:
            n_tank[how] = 0 if tank is None else max(
                mesh_tank_around(sensor, tank, sensor_axis_points_m(Scene(sensor, Pose.from_array(p), tank), 9),
                                 *how).n_triangles for p in poses)
        Ns, Ne = estimate_triangles(sensor, opts.get("edge_length_m")), n_tank[how] + n_objects
        needs.append((max(pose_bytes(Ns, Ne), dense_system_bytes(Ns, 1.1)),
                      f"a {'reference' if name == 'ref' else name} BEM pose nearest a wall (tank and objects {Ne} "
                      f"triangles, sensor {Ns})"))
    what = " and ".join(w for _, w in needs) + (" together" if len(needs) > 1 else "")
    check_bytes(sum(b for b, _ in needs), what, 0.8 * memory_share,
                hint="use fewer workers (--workers), a coarser reference sensor mesh (--edge-length) or a wider "
                     "wall gap (--wall-gap)")


class _BemPool:
    """The BEM at many poses on ``workers`` processes (each pose on its own tank mesh, so a pose's K does not
    depend on which worker solved it), on the coarse or the reference sensor mesh. ``cpu_s``:
    CPU seconds of the worker processes (with one worker everything runs in this process, whose own CPU time
    counts it). ``hardest``: poses at which the workers' memory is checked first (:func:`check_pose_memory`)."""

    def __init__(self, sensor, tank, objects, options: dict, workers: int, hardest=None):
        self.workers = max(1, int(workers))
        # every worker holds a sweep of each mesh: their sum is checked against the worker's share here, and each
        # sweep checks itself against that share
        self.args = (sensor, tank, tuple(objects), options, 1.0 / self.workers)
        if hardest is not None and (tank is not None or objects):
            check_pose_memory(sensor, tank, objects, options, hardest, self.args[-1])
        self._cpu = {}
        self.solved = 0
        self._pool = None
        self._warming = None   # the future of the reference sweep's set-up ahead of its poses
        if self.workers > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn (OpenMP forbids fork): a script that builds a map with workers needs `if __name__ == "__main__":`
            self._pool = ProcessPoolExecutor(self.workers, mp.get_context("spawn"), _pool_worker_init, self.args)
            if "ref" in options:
                # the reference sensor block (a random 5-electrode sensor: 11 000 triangles, 19 s of CPU) set up
                # by one worker while the others solve the first coarse poses, and read from the disk cache by
                # the others, rather than made by every worker at the first reference round
                self._warming = self._pool.submit(_worker_prepare, "ref")
        else:
            _worker_init(*self.args)

    @property
    def cpu_s(self) -> float:
        return float(sum(self._cpu.values()))

    def solve(self, poses: np.ndarray, fidelity: str = "coarse") -> np.ndarray:
        self.solved += len(poses)
        if self._pool is None:
            return _worker_solve(poses, fidelity)[0]
        # one pose a task: a pose near a wall has a finer tank mesh and costs up to 4x one mid-tank, so equal
        # shares left a worker idle
        parts = [poses[i:i + 1] for i in range(len(poses))]
        out = list(self._pool.map(_worker_solve, parts, [fidelity] * len(parts)))
        done = []
        if self._warming is not None and self._warming.done():   # its failure: the same error comes with the
            done = [self._warming.result()] if self._warming.exception() is None else []   # poses themselves
            self._warming = None
        for pid, cpu in [(pid, cpu) for _, pid, cpu in out] + done:
            self._cpu[pid] = max(cpu, self._cpu.get(pid, 0.0))
        return np.concatenate([K for K, _, _ in out])

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)


def build_tank_map(sensor, tank, z_m, path=None, objects=(), target: float = TARGET_RMS,
                   target_max: float = TARGET_MAX, wall_gap_m: float = 0.005, spacing_m: float = 0.01,
                   n_headings: int = 48, n_depths: int = 5, first: int = 60, first_tips: int = 30,
                   first_corners: int = 30, first_band_corners: int = 24, per_round: int = 24,
                   first_ref: int = 12, max_seconds: float = 270.0, max_cpu_seconds: float | None = None,
                   bem_options: dict | None = None, coarse_factor: float = COARSE_FACTOR,
                   sigma_S_per_m: float | None = None, workers: int = 2, warp_m: float = DEFAULT_WARP_M,
                   progress=None) -> TankMap:
    """Build (or resume, from ``path``) the map of ``sensor`` in ``tank`` at depth ``z_m`` (module doc).

    ``z_m``: a depth (m, tank frame) or ``(z_min, z_max)`` for a band (``n_depths`` candidate depths);
    ``target`` / ``target_max``: the RMS and largest estimated relative error of a receiver current over the
    candidates at which the build stops; ``bem_options``: of the reference BEM, the one the map reproduces
    (its sensor mesh ``edge_length_m`` defaults to the mesher's, as everywhere else in the project);
    ``first`` / ``first_tips``: the first round's poses, spread over the grid and then over the tips at the
    gap (:func:`tips_at_the_gap`; without them seed 4's map erred 0.09-0.17 % with a tip 5 mm from the middle of
    a wall, and 56 coarse poses there, 30 s of CPU, took 36 such poses from 0.053 % / 0.117 % to 0.016 % /
    0.026 %), then over ``first_corners`` poses at the gap from two walls at once (:func:`corners_at_the_gap`),
    then, in a box, over ``first_band_corners`` poses at random gaps from two walls within :data:`CORNER_BAND`
    times the gap and at random headings (:func:`corner_poses`; the candidates stay for the later rounds);
    ``coarse_factor``: the many poses are solved on a sensor mesh this much coarser (at most as coarse as the
    mesher makes it, :func:`~electrosense.meshes.sensor_mesh.coarsest_edge_length_m`) and corrected by the
    reference at fewer poses (``first_ref`` first, then a round of them where it removes more of the
    estimated error per CPU second than a round of coarse ones, :func:`_refine_pays`, at the nodes where the
    correction's estimated error is largest and a share, :data:`REFERENCE_SPREAD_SHARE`, spread over the tank;
    1: every pose on the reference mesh); ``max_cpu_seconds``: CPU
    budget of the whole build, every process counted (default ``workers * max_seconds``: on a machine busy with other work the same command solves the
    same BEM poses and gives the same map); ``max_seconds``: wall-clock budget; at either the map is saved as it
    stands, its estimated error with it (the last round is as many poses as the CPU budget still pays for);
    ``workers``: processes solving the BEM (fewer, said, where their BEM poses nearest a wall would not fit in the
    memory together; the CPU budget stays ``workers * max_seconds``).
    """
    from electrosense.bem.solve import check_object_materials
    from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING, SceneError, object_problems
    from electrosense.meshes.sensor_mesh import coarsest_edge_length_m, default_edge_length_m
    from electrosense.validation.diagnosis.anchored import pose_features
    from electrosense.validation.simulation.models import code_version, free_space_bem

    say = progress or (lambda s: None)
    t0, c0 = time.perf_counter(), time.process_time()
    max_cpu_seconds = workers * max_seconds if max_cpu_seconds is None else max_cpu_seconds
    objects = tuple(objects)
    check_object_materials(objects)   # before any candidate or BEM pose: the scene's own faults, said at once
    problems = object_problems(tank, objects)
    if problems:
        raise SceneError(problems)
    options = dict(bem_options or {})
    if options.get("edge_length_m") is None:
        options["edge_length_m"] = default_edge_length_m(sensor)
    coarse_factor = float(coarse_factor)
    if not coarse_factor >= 1.0:
        raise ValueError(f"coarse_factor must be 1 or more, got {coarse_factor}")
    coarse_edge_m = min(coarse_factor * options["edge_length_m"], coarsest_edge_length_m(sensor))
    if coarse_edge_m < coarse_factor * options["edge_length_m"]:   # a reference edge near the sensor's diameter
        coarse_factor = max(1.0, coarse_edge_m / options["edge_length_m"])
        say(f"the coarse sensor mesh at the sensor's diameter ({1e3 * coarse_edge_m:.2f} mm): "
            f"{coarse_factor:.2f}x the reference's edge" if coarse_factor > 1.0
            else "the reference's sensor mesh is as coarse as the mesher makes it: every pose on it")
    corrected = coarse_factor > 1.0
    if options.get("tank_grading") is None and tank is not None:
        options["tank_grading"] = REFERENCE_TANK_GRADING if corrected else DEFAULT_TANK_GRADING
    fidelities = bem_fidelities(tank, options, coarse_edge_m)
    images_m = fidelities["ref"].get("image_faces_within_m")   # the reference's images, written with the map
    code = code_version()
    band = np.ndim(z_m) > 0
    if band:
        z0, z1 = sorted(float(v) for v in z_m)
        z_m = (z0, z1)
        depths = np.linspace(z0, z1, max(2, n_depths))
    else:
        z_m = float(z_m)
        depths = np.array([z_m])
    C = reachable_poses(sensor, tank, depths, wall_gap_m, spacing_m, n_headings, objects)
    if not len(C):
        raise ValueError(f"no pose at depth z = {z_m} m keeps the sensor {wall_gap_m} m from the walls")
    # the tips facing a wall square on, to within half the grid's heading step (one heading a wall position)
    tips = tips_at_the_gap(sensor, tank, C, wall_gap_m, spacing_m, objects, facing_rad=np.pi / n_headings)
    # and the sensor at the gap from two walls at once, where the grid leaves the corner to the interpolant
    corners = np.unique(np.round(corners_at_the_gap(sensor, tank, C, wall_gap_m, spacing_m, objects), 9), axis=0)
    # and, in a box, at random gaps from two walls between that gap and CORNER_BAND times it, at random headings
    band_corners = np.zeros((0, 4))
    if tank is not None and "wall_x+" in tank.region_names and first_band_corners:
        rng = np.random.default_rng(CORNER_BAND_SEED)     # the same candidates each time: a build resumes
        gap_band = (CORNER_BAND[0] * wall_gap_m, CORNER_BAND[1] * wall_gap_m)
        per_depth = int(np.ceil(CORNER_BAND_CANDIDATES * max(first_band_corners, 1) / len(depths)))
        band_corners = np.vstack([corner_poses(sensor, tank, zz, rng, per_depth, None, gap_band, objects)
                                  for zz in depths])
    kind = np.r_[np.zeros(len(C), int), np.ones(len(tips), int), np.full(len(corners), 2),
                 np.full(len(band_corners), 3)]   # grid, tip, corner at the gap, corner in the band
    C = np.vstack([C, tips, corners, band_corners])
    frame = MapFrame(sensor, tank, objects, band, warp_m)
    F = frame.features(C)
    if frame.symmetric:   # one candidate per orbit, at its folded pose: the BEM's poses all lie in the
        # fundamental domain (MapFrame.folded), where every pose is evaluated
        _, keep = np.unique(np.round(F / 1e-6).astype(np.int64), axis=0, return_index=True)
        keep = np.sort(keep)
        C, F, kind = frame.folded(C[keep]), F[keep], kind[keep]
    T = pose_features(sensor, C)   # the tips' positions: where a round's spread share goes
    say(f"{len(C)} candidate poses (grid {spacing_m} m, {n_headings} headings, {len(depths)} depth(s), "
        f"{wall_gap_m * 1e3:g} mm from the walls, {int(np.sum(kind == 1))} of them a tip at that gap, "
        f"{int(np.sum(kind == 2))} at that gap from two walls"
        f"{f', {int(np.sum(kind == 3))} at random gaps from two walls up to {CORNER_BAND[1]:g}x it' if np.any(kind == 3) else ''}"
        f"{', folded by the tank symmetry' if frame.symmetric else ''})")
    K_free = free_space_bem(sensor, options["edge_length_m"]).K_S
    n = K_free.shape[0]
    nodes, K_nodes, history = np.zeros((0, 4)), np.zeros((0, n, n)), []
    ref_index, K_ref = np.zeros(0, int), np.zeros((0, n, n))
    if path is not None and Path(path).exists():
        try:
            old = load_tank_map(path)
        except ValueError as exc:
            raise ValueError(f"{exc}; remove it or choose another output file") from None
        same = (old.sensor.to_dict() == sensor.to_dict() and same_scene(old.tank, old.objects, tank, objects, 1e-12)
                and old.z_m == z_m and old.code == code and old.warp_m == warp_m
                and old.coarse_factor == coarse_factor
                and old.bem_options == {k: v for k, v in options.items() if isinstance(v, (int, float, str))})
        if not same:
            raise ValueError(f"{path} holds a map of another scene, depth, BEM or code version; remove it or "
                             "choose another output file")
        nodes, K_nodes, history = old.nodes, old.K_nodes, list(old.history)
        ref_index, K_ref = old.ref_index, old.K_ref
        say(f"resuming from {len(nodes)} BEM poses ({len(ref_index)} on the reference mesh) in {path}")
    # the memory checked at the poses nearest a wall (the finest tank meshes) before any BEM; where the workers'
    # sweeps do not fit together, fewer workers, said (one that does not fit alone is refused)
    from electrosense.bem.memory import MemoryRefusal

    nearest = C[np.argsort(sensor_wall_gap_m(sensor, tank, C, objects))[:2]]
    for w in range(max(1, int(workers)), 0, -1):
        try:
            pool = _BemPool(sensor, tank, objects, fidelities if corrected else {"coarse": fidelities["ref"]}, w,
                            nearest)
            break
        except MemoryRefusal as exc:
            if w == 1:
                raise
            reason = str(exc).split(": use ")[0]   # the numbers, not the remedy: this is it
            say(f"  memory: {w} workers would not hold their BEM poses nearest a wall ({reason}); {w - 1} instead")
    prior_cpu = float(history[-1].get("cpu_seconds", 0.0)) if history else 0.0
    prior_wall = float(history[-1].get("seconds", 0.0)) if history else 0.0
    per_pose = {}   # CPU seconds per pose of each mesh, set-up included (an upper estimate)

    def cpu_now():
        return time.process_time() - c0 + pool.cpu_s

    def solve(idx):
        nonlocal nodes, K_nodes
        c = cpu_now()
        K = pool.solve(C[idx], "coarse")
        per_pose["coarse"] = (cpu_now() - c) / len(idx)
        nodes, K_nodes = np.vstack([nodes, C[idx]]), np.vstack([K_nodes, K])

    def solve_ref(node_idx):
        nonlocal ref_index, K_ref
        c = cpu_now()
        K = pool.solve(nodes[node_idx], "ref")
        per_pose["ref"] = (cpu_now() - c) / len(node_idx)
        ref_index, K_ref = np.r_[ref_index, node_idx], np.vstack([K_ref, K])

    def current_map():
        return TankMap(sensor, tank, z_m, nodes, K_nodes, K_free, objects, options, code, wall_gap_m, history,
                       sigma_S_per_m, warp_m, None, coarse_factor, ref_index, K_ref, None, images_m)

    try:
        def affordable(fidelity: str) -> int:
            """How many more poses of ``fidelity`` the CPU budget pays for, at their cost as measured so far (none
            once the wall-clock budget is spent)."""
            left = max_cpu_seconds - prior_cpu - cpu_now()
            if time.perf_counter() - t0 > max_seconds or left <= 0:
                return 0
            cost = per_pose.get(fidelity)
            return int(left // cost) if cost else len(C)

        def spent(fidelity: str, k: int) -> bool:
            """The budget cannot pay for ``k`` more poses of ``fidelity``."""
            return affordable(fidelity) < k

        # the first poses in chunks, the budget checked between them (a slow scene gets fewer, never none): at
        # least one chunk of coarse poses and MIN_REFERENCE_POSES on the reference mesh make a map with its error
        n_tips = first + min(first_tips, int(np.sum(kind == 1)))
        n_corners = n_tips + min(first_corners, int(np.sum(kind == 2)))
        n_first = n_corners + min(first_band_corners, int(np.sum(kind == 3)))
        if len(nodes) < n_first:
            say(f"BEM at {n_first - len(nodes)} first poses on {pool.workers} process(es)"
                + (f", sensor mesh {coarse_factor:.3g}x coarser than the reference" if corrected else ""))
            # spread over the grid, then over the tips at the gap (the tips the grid misses, where log K changes
            # fastest: tips_at_the_gap; cheap on the coarse poses, whose faces near the sensor are image planes),
            # then over the corners at the gap (corners_at_the_gap), then over those in the band (corner_poses)
            have = frame.features(nodes) if len(nodes) else np.zeros((0, F.shape[1]))
            order = np.zeros(0, int)
            for k, upto in ((0, first), (1, n_tips), (2, n_corners), (3, n_first)):
                pool_k = np.flatnonzero(kind == k)
                pick = pool_k[_farthest_points(F[pool_k], max(0, upto - len(nodes) - len(order)),
                                               have if len(have) else None)]
                order, have = np.r_[order, pick], np.vstack([have, F[pick]])
            for chunk in np.array_split(order, int(np.ceil(len(order) / per_round))):
                if len(nodes) and spent("coarse", len(chunk)):
                    say(f"time budget spent after {len(nodes)} first poses")
                    break
                solve(chunk)
        if corrected and len(ref_index) < first_ref:
            say(f"reference BEM at up to {first_ref - len(ref_index)} of them (sensor mesh edge "
                f"{1e3 * options['edge_length_m']:.2f} mm)")
            X = frame.features(nodes)
            # among the grid's first poses, not the tips at the gap after them: the correction is smooth there
            # (seed 4's box: 0.005-0.025 % at 16 such poses from none of them), and a reference pose there costs
            # its wall's mesh
            grid_first = np.setdiff1d(np.arange(min(first, len(nodes))), ref_index)
            spread = grid_first[_farthest_points(X[grid_first], min(first_ref - len(ref_index), len(grid_first)),
                                                 X[ref_index] if len(ref_index) else None)]
            for chunk in np.array_split(spread, int(np.ceil(len(spread) / MIN_REFERENCE_POSES))) if len(spread) else []:
                if len(ref_index) >= MIN_REFERENCE_POSES and spent("ref", len(chunk)):
                    say(f"time budget spent after {len(ref_index)} reference poses")
                    break
                solve_ref(chunk)
        while True:
            m = current_map()
            err_c = m.coarse_error_at(F).max(axis=1)
            err_r = m.correction_error_at(C, F).max(axis=1) if corrected else np.zeros(len(C))
            err = np.hypot(err_c, err_r)
            rms = float(np.sqrt(np.mean(err**2)))
            rms_c, rms_r = float(np.sqrt(np.mean(err_c**2))), float(np.sqrt(np.mean(err_r**2)))
            wall = prior_wall + time.perf_counter() - t0
            cpu = prior_cpu + cpu_now()
            history.append({"bem_poses": len(nodes), "reference_poses": int(len(ref_index)),
                            "max_error": float(err.max()), "rms_error": rms, "rms_error_coarse": rms_c,
                            "rms_error_correction": rms_r, "seconds": wall, "cpu_seconds": cpu})
            m.history = history
            if path is not None:
                m.save(path)
            say(f"{len(nodes)} BEM poses{f' ({len(ref_index)} on the reference mesh)' if corrected else ''}: "
                f"estimated error RMS {100 * rms:.4f} %, max {100 * err.max():.4f} % (target {100 * target:.4f} % / "
                f"{100 * target_max:.4f} %){f'; interpolation {100 * rms_c:.4f} %, correction {100 * rms_r:.4f} %' if corrected else ''}, "
                f"{wall:.0f} s")
            if rms <= target and err.max() <= target_max:
                break
            # the next round: more coarse poses, or more reference ones, whichever buys more (_refine_pays)
            refine = corrected and len(ref_index) < len(nodes) and _refine_pays(
                rms_c, len(nodes), per_pose.get("coarse"), rms_r, len(ref_index), per_pose.get("ref"))
            # the last round is what the budget still pays for (a cylinder's 24 coarse poses cost 160 s of CPU:
            # whole rounds left up to that unspent), and its last seconds go to the cheaper coarse poses
            k = min(max(4, per_round // 3) if refine else per_round, affordable("ref" if refine else "coarse"))
            if refine and k < pool.workers:
                refine, k = False, min(per_round, affordable("coarse"))
            if k < pool.workers:
                say(f"time budget spent ({wall:.0f} s of {max_seconds:.0f} s wall, {cpu:.0f} s of "
                    f"{max_cpu_seconds:.0f} s CPU): the map is saved with its estimated error")
                break
            if refine:
                X = frame.features(nodes)
                e_nodes = m.correction_error_at(nodes, X).max(axis=1)
                picked = reference_round(X, pose_features(sensor, nodes), e_nodes, ref_index, k)
                solve_ref(picked)
                history[-1]["next_round"] = estimate_checked(m, nodes[picked], K_ref[-len(picked):], "ref")
            else:   # most where the estimated error is largest, a share spread over the tank (module doc)
                picked = np.unique(spread_round(F, T, err_c, m._parts[0].X, pose_features(sensor, nodes), k,
                                                EXPLORE_SHARE))
                solve(picked)
                history[-1]["next_round"] = estimate_checked(m, C[picked], K_nodes[-len(picked):], "coarse")
    finally:
        pool.close()
    return m


# ------------------------------------------------------------------ as a model
@dataclass
class MapEvaluator:
    """A :class:`TankMap` as a model of :func:`~electrosense.validation.simulation.models.pose_evaluator`:
    ``.conductance(poses) -> ConductanceMatrix`` at ``sigma_S_per_m``; refuses poses off the map's depth or
    closer to a wall than it was built for (an interpolant does not extrapolate)."""

    tank_map: TankMap
    sigma_S_per_m: float

    def conductance(self, poses, progress: bool = False):
        from electrosense.bem.conductance import ConductanceMatrix

        poses = np.asarray(poses, float).reshape(-1, 4)
        m = self.tank_map
        inside, why = m.covers(poses)
        if not inside.all():
            raise ValueError(why)
        return ConductanceMatrix(m.conductance(poses, self.sigma_S_per_m), m.sensor.emitter, self.sigma_S_per_m,
                                 {"model": "map", "bem_poses": int(len(m.nodes))})
