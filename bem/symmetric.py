"""The collocation BEM of a rotationally symmetric sensor alone in unbounded water, mode by mode.

A sector sensor's mesh (:mod:`electrosense.meshes.sector_mesh`) is ``M`` copies of one
wedge rotated about the x axis, triangle ``t`` of wedge ``w`` at index
``w T + t``. The collocation integrals depend only on the relative position
of target and source, so the single and double layer are *block circulant*:
the block from wedge ``a``'s targets to wedge ``b``'s sources is the block from
wedge 0 to wedge ``b - a``.

The mixed system (:mod:`electrosense.bem.system`) keeps that structure under every
rotation that maps each triangle's boundary-condition type (insulator,
electrode, contact impedance) onto the same type: rotations by ``2 pi / G``,
``G`` the largest divisor of ``M`` for which that holds (every rotation of the
mesh when the sectors touch, since a gap of 0 leaves the types the same all
round; the rotations that map the gaps onto gaps otherwise). The electrode
*numbers* need not be invariant: only the right-hand sides (one per
electrode) are not, and they are any vectors. With ``G`` blocks of
``n = N / G`` triangles, the discrete Fourier transform over the blocks turns
the ``N x N`` system into ``G`` independent ``n x n`` complex systems (the
azimuthal modes ``m = 0 .. G-1``; ``m`` and ``G - m`` are complex conjugates,
so ``G // 2 + 1`` are solved)::

    A_m = sum_d C_d exp(+2 pi i m d / G),   A_m x_m = r_m,   r_m = sum_a r_a exp(-2 pi i m a / G),

``C_d`` the block from block 0's targets to block ``d``'s sources. Only block
0's rows are assembled (``N^2 / G`` pairs instead of ``N^2``) and the solve
costs ``(G / 2 + 1) (8/3) n^3`` real operations instead of ``(2/3) N^3``: with
``G = 4`` about 4 times less assembly and 10 times less factorisation. The
answer is the full collocation's, to rounding (``tests/test_sector_bem.py``).

Modes 0 and ``G / 2`` are real and solved in real arithmetic. The same
algebra holds for two blocks that are mirror images (``mirror=True``: a
sensor that no rotation maps onto itself, :func:`electrosense.meshes.sector_mesh.block_symmetry`).
With ``G = 1`` (boundary conditions with no symmetry, e.g. contact
impedances that differ between mirror-image sectors) nothing is gained and
:func:`solve_symmetric` returns the full collocation.

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.bem.boundary_conditions import WaterBoundary
>>> s = preset("angels-2").with_sectors({1: 2}, gap_m=0.002)
>>> wb = WaterBoundary.from_meshes(mesh_sensor(s, 0.012), allow_touching=True)
>>> sol = solve_symmetric(wb, 1.0, order=2, emitter=s.emitter)
>>> sol.info["method"], sol.info["blocks"]
('symmetric blocks', 2)
"""
from __future__ import annotations

import time

import numpy as np

from electrosense.bem.boundary_conditions import BoundaryError, WaterBoundary
from electrosense.bem.conductance import check_conductivity
from electrosense.bem.linear_solve import solve_dense
from electrosense.bem.system import BemSystem, assemble_system, boundary_columns

__all__ = ["solve_symmetric", "type_symmetry_blocks", "is_rotation_symmetric"]


def is_rotation_symmetric(boundary: WaterBoundary, order: int, rtol: float = 1e-9) -> bool:
    """True when the triangles are ``order`` equal blocks, block ``a`` block 0 turned by ``2 pi a / order`` about +x."""
    tri = boundary.triangles_m
    if order < 1 or len(tri) % order:
        return False
    n = len(tri) // order
    scale = np.abs(tri).max()
    for a in range(1, order):
        c, s = np.cos(2 * np.pi * a / order), np.sin(2 * np.pi * a / order)
        t0 = tri[:n]
        turned = np.stack([t0[..., 0], c * t0[..., 1] - s * t0[..., 2], s * t0[..., 1] + c * t0[..., 2]], axis=-1)
        if np.abs(turned - tri[a * n:(a + 1) * n]).max() > rtol * scale:
            return False
    return True


def is_mirror_symmetric(boundary: WaterBoundary, rtol: float = 1e-9) -> bool:
    """True when the triangles are two equal blocks, block 1 block 0's mirror image in the x-y plane (z -> -z)."""
    tri = boundary.triangles_m
    if len(tri) % 2:
        return False
    n = len(tri) // 2
    c0, c1 = tri[:n].mean(axis=1), tri[n:].mean(axis=1)
    scale = np.abs(tri).max()
    n0 = np.cross(tri[:n, 1] - tri[:n, 0], tri[:n, 2] - tri[:n, 0])
    n1 = np.cross(tri[n:, 1] - tri[n:, 0], tri[n:, 2] - tri[n:, 0])
    flip = np.array([1.0, 1.0, -1.0])
    return bool(np.abs(c1 - c0 * flip).max() <= rtol * scale
                and np.abs(n1 - n0 * flip).max() <= rtol * scale**2)


def type_symmetry_blocks(c_single: np.ndarray, c_double: np.ndarray, order: int) -> int:
    """Largest divisor ``G`` of ``order`` such that shifting the triangles by ``N / G`` keeps every column's type."""
    N = len(c_single)
    for G in sorted((d for d in range(1, order + 1) if order % d == 0), reverse=True):
        shift = N // G
        if np.array_equal(np.roll(c_single, shift), c_single) and np.array_equal(np.roll(c_double, shift), c_double):
            return G
    return 1


def _weighted_block_sum(blocks: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``sum_d weights[d] blocks[:, d]`` of the (n, G, n) blocks (``weights[0]`` is 1: the mode's ``cos 0`` or,
    for the imaginary part, ``sin 0`` = 0), accumulated in place: a weight of +-1 costs no temporary."""
    out = blocks[:, 0] * weights[0]
    for d in range(1, len(weights)):
        w = weights[d]
        if abs(w - 1.0) < 1e-15:
            out += blocks[:, d]
        elif abs(w + 1.0) < 1e-15:
            out -= blocks[:, d]
        elif abs(w) > 1e-15:
            out += w * blocks[:, d]
    return out


def solve_symmetric(boundary: WaterBoundary, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                    emitter: int | None = None, order: int = 1, incident_potential_V=None, mirror: bool = False):
    """Unit solutions of a mesh made of ``order`` rotated copies of one wedge, alone in unbounded water.

    Returns a :class:`electrosense.bem.solution.BemSolution` equal (to rounding) to
    :func:`electrosense.bem.solution.solve`'s; ``info["blocks"]`` is the ``G`` used.

    ``incident_potential_V`` (F, r), optional: ``r`` incident potentials at the
    triangles' centroids (harmonic fields with no source near the sensor, e.g.
    ``-y`` for a unit field along +y). ``mirror``: the two blocks (``order``
    2) are mirror images in the x-y plane instead of turned by pi (the same
    algebra: any isometry of order two makes the matrix 2-block circulant).
    With every electrode held at 0 V the
    total potential ``u = u_inc + u_scattered`` satisfies
    ``(1/2 + D) u - S q = u_inc`` on the boundary (Green's identity for
    ``u_inc`` inside the body), the same system with ``u_inc`` as right-hand
    side; ``info["incident_currents_A"]`` (n, r) holds the currents then
    leaving each electrode into the water, and ``solution.incident_unknowns``
    (F, r) the unknowns (potential on insulators, ``l q`` on electrodes).
    """
    from electrosense.bem.operators import FAR, mixed_system
    from electrosense.bem.solution import solve, unit_solutions

    t0 = time.perf_counter()
    sigma_S_per_m = check_conductivity(sigma_S_per_m)
    if not boundary.unbounded or boundary.n_conductors or len(boundary.part_names) != 1:
        raise BoundaryError("the symmetric solve is for a lone sensor in unbounded water")
    if mirror:
        if order != 2 or not is_mirror_symmetric(boundary):
            raise BoundaryError("the sensor mesh is not two mirror-image halves (z -> -z)")
    elif not is_rotation_symmetric(boundary, order):
        raise BoundaryError(f"the sensor mesh is not {order} rotated copies of one wedge")
    n_el = boundary.n_electrodes
    emitter = n_el if emitter is None else int(emitter)
    tris, z_c, scale, cs, cd, group = boundary_columns(boundary, sigma_S_per_m, contact_impedance_ohm_m2)
    G = type_symmetry_blocks(cs, cd, order)
    N = len(tris)
    labels = boundary.electrode
    incident = np.zeros((N, 0)) if incident_potential_V is None else np.asarray(incident_potential_V, float)
    incident = incident.reshape(N, -1)

    def with_incident(solution, x_incident):
        if incident.shape[1]:
            on_e = labels > 0
            currents = np.zeros((n_el, incident.shape[1]))
            np.add.at(currents, labels[on_e] - 1, (sigma_S_per_m / scale) * tris.areas[on_e, None] * x_incident[on_e])
            solution.info["incident_currents_A"] = currents.tolist()
            solution.incident_unknowns = x_incident     # (F, r): as ``unknowns``, every electrode at 0 V
        return solution

    if G == 1:
        method = "full collocation (no symmetry of the boundary conditions)"
        if not incident.shape[1]:
            solution = solve(boundary, sigma_S_per_m, contact_impedance_ohm_m2, emitter)
            solution.info.update(method=method, blocks=1)
            return solution
        system = assemble_system(boundary, sigma_S_per_m, contact_impedance_ohm_m2)
        t1 = time.perf_counter()
        x, rcond, _ = solve_dense(system.matrix, np.hstack([system.rhs, incident]))
        solution = unit_solutions(boundary, sigma_S_per_m, system, x[:, :n_el], emitter,
                                  {"assembly_s": t1 - t0, "solve_s": time.perf_counter() - t1, "method": method,
                                   "blocks": 1, "rcond": rcond})
        return with_incident(solution, x[:, n_el:])
    n = N // G
    own = np.arange(n)
    # the electrode each triangle's place holds in every turned labelling: block a's rows see the labels turned
    # back by a blocks, so its right-hand side for electrode g sums H over the columns j with labels[j + a n] = g
    turned = np.stack([np.roll(labels, -a * n) for a in range(G)], axis=1)        # (N, G)
    patterns, group = np.unique(turned, axis=0, return_inverse=True)
    group = group.ravel()
    # block 0's rows of A = c_single S + c_double H in one pass, with H summed over each pattern's columns
    S0, H_sums = mixed_system(tris.centroids[:n], tris, own, cs, cd, group, len(patterns), far=FAR)
    rhs = np.empty((G, n, n_el + incident.shape[1]))
    for a in range(G):
        for g in range(n_el):
            rhs[a, :, g] = -H_sums[:, patterns[:, a] == g + 1].sum(axis=1)
        rhs[a, :, n_el:] = incident[a * n:(a + 1) * n]
    blocks = S0.reshape(n, G, n)                             # blocks[:, d]: block 0's targets x block d's sources
    rhs_hat = np.fft.fft(rhs, axis=0)
    t1 = time.perf_counter()
    x_hat = np.empty(rhs.shape, dtype=complex)
    rconds = []
    for m in range(G // 2 + 1):
        # A_m = sum_d C_d exp(2 pi i m d / G), summed directly in real arithmetic (an FFT over a short, strided
        # axis of a large array is several times slower)
        angle = 2 * np.pi * m * np.arange(G) / G
        real = _weighted_block_sum(blocks, np.cos(angle))
        if m == 0 or 2 * m == G:   # real modes: real arithmetic
            x, rcond, _ = solve_dense(real, rhs_hat[m].real.copy(), what=f"BEM system of mode {m}")
            x_hat[m] = x
        else:
            mode = real + 1j * _weighted_block_sum(blocks, np.sin(angle))
            del real
            x_hat[m], rcond, _ = solve_dense(mode, rhs_hat[m], what=f"BEM system of mode {m}")
        rconds.append(rcond)
        if 0 < m < G - m:
            x_hat[G - m] = np.conj(x_hat[m])
    x = np.fft.ifft(x_hat, axis=0).real.reshape(N, -1)
    t2 = time.perf_counter()
    del S0, blocks
    system = BemSystem(matrix=None, rhs=None, scale_m=scale, z_c=z_c, n_conductors=0)
    solution = unit_solutions(boundary, sigma_S_per_m, system, x[:, :n_el], emitter,
                              {"assembly_s": t1 - t0, "solve_s": t2 - t1, "method": "symmetric blocks",
                               "blocks": G, "rcond": float(min(rconds))})
    return with_incident(solution, x[:, n_el:])
