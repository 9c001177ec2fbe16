"""Sensitivity of four-electrode transfer impedances to electrode positions, from one solve (reciprocity).

Moving a small measurement electrode ``p`` by ``dx`` along the boundary
changes the potential it reads by ``grad u_ab(x_p) . dx``: the field of the
drive solution at the electrode. A drive electrode moves the same way by
reciprocity, ``Z(a, b; p, q) = Z(p, q; a, b)``, with the field of the
solution that drives the measurement pair. So every derivative

    dZ(a, b; p, q)/dx_e = [e = p] g_ab(e) - [e = q] g_ab(e) + [e = a] g_pq(e) - [e = b] g_pq(e)

needs only the tangential derivatives ``g_pair(e)`` of the potentials of the
unit-current solutions of the drive and measurement pairs, all taken from
the one surface solution (no solve per electrode).

The derivative of the undisturbed potential is taken by central differences
at ``x_e - depth * n_e +- step * t_e`` (``n_e`` the boundary's outward normal,
``t_e`` a unit tangent). The floating electrode itself bends the field near
its rim; that disturbance falls off as ``(radius / step)^3``, so ``step`` of a
few radii is far enough (the default is 3 radii; checked against the
closed-form series of a cylinder in the real_tank study's notes).

Example
-------
>>> import numpy as np
>>> u = {(1, 2): np.array([0.0, 2.0]), (3, 2): np.array([1.0, 0.0])}
>>> combine_shift_sensitivities([(1, 2)], [(3, 2)], u, electrodes=[1, 3]).tolist()
[[[1.0, 2.0]]]
"""
from __future__ import annotations

import numpy as np

from electrosense.bem.protocol import node_potentials_V

__all__ = ["pair_gradients", "combine_shift_sensitivities", "shift_sensitivities_ohm_per_m"]


def pair_gradients(solution, pairs, centres_m, normals_out, tangents, step_m, depth_m) -> np.ndarray:
    """(P, E) tangential derivative (V/(A m)) at each electrode e of the potential of 1 A through each pair.

    ``centres_m``, ``normals_out`` (out of the water), ``tangents`` (unit) and
    ``step_m``, ``depth_m`` are per electrode (E,...).
    """
    from electrosense.bem.fields import potential_at

    c = np.asarray(centres_m, float).reshape(-1, 3)
    n = np.asarray(normals_out, float).reshape(-1, 3)
    t = np.asarray(tangents, float).reshape(-1, 3)
    h = np.broadcast_to(np.asarray(step_m, float), (len(c),))[:, None]
    dep = np.broadcast_to(np.asarray(depth_m, float), (len(c),))[:, None]
    base = c - dep * n
    pts = np.concatenate([base + h * t, base - h * t])
    V = node_potentials_V(solution.K_S, pairs)          # (P, n) electrode potentials per unit current
    u = np.stack([potential_at(solution, pts, v) for v in V])   # (P, 2E)
    E = len(c)
    return (u[:, :E] - u[:, E:]) / (2 * h[:, 0])


def combine_shift_sensitivities(drive_pairs, measure_pairs, gradients: dict, electrodes) -> np.ndarray:
    """(D, M, E) dZ/dx_e (ohm/m) from the per-pair gradients ``gradients[(a, b)]`` (E,) at the electrodes.

    ``Z(a, b; p, q) = V_p - V_q`` for 1 A into ``a`` and out of ``b``.
    """
    d = np.asarray(drive_pairs, np.int64).reshape(-1, 2)
    m = np.asarray(measure_pairs, np.int64).reshape(-1, 2)
    el = np.asarray(electrodes, np.int64).ravel()
    J = np.zeros((len(d), len(m), len(el)))
    for i, (a, b) in enumerate(d.tolist()):
        g_ab = gradients[(a, b)]
        for j, (p, q) in enumerate(m.tolist()):
            g_pq = gradients[(p, q)]
            J[i, j] += (el == p) * g_ab - (el == q) * g_ab + (el == a) * g_pq - (el == b) * g_pq
    return J


def shift_sensitivities_ohm_per_m(solution, drive_pairs, measure_pairs, electrodes, centres_m, normals_out,
                                  tangents, radii_m, step_radii: float = 3.0) -> np.ndarray:
    """(D, M, E) derivatives of every transfer impedance w.r.t. moving electrode e along ``tangents[e]``.

    One surface solution serves all: the fields of the unit-current
    solutions of the drive and measurement pairs are sampled beside each
    electrode (``step_radii`` radii either side, one radius into the water).
    """
    d = np.asarray(drive_pairs, np.int64).reshape(-1, 2)
    m = np.asarray(measure_pairs, np.int64).reshape(-1, 2)
    pairs = np.unique(np.concatenate([d, m]), axis=0)
    a = np.asarray(radii_m, float)
    g = pair_gradients(solution, pairs, centres_m, normals_out, tangents, step_radii * a, a)
    grads = {tuple(p): g[i] for i, p in enumerate(pairs.tolist())}
    return combine_shift_sensitivities(d, m, grads, electrodes)
