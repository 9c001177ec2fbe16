"""Ring boundary elements on the meridian of a sensor of revolution in unbounded water (or facing a wall).

A sensor of :mod:`electrosense.meshes.sensor` (cylinder, hemispherical ends, electrodes
that are caps or rings) alone in unbounded water has an axisymmetric
solution for every pattern of electrode potentials. Integrating the Laplace
kernel ``G = 1/(4 pi |x - y|)`` around the axis turns the surface integrals
into integrals along the meridian (arc length ``s``, axial coordinate ``x``,
radius ``r``) with the classical ring kernels (``m`` the parameter of the
complete elliptic integrals ``K(m)``, ``E(m)``)::

    a^2 = (r + r')^2 + (x - x')^2,   b^2 = (r - r')^2 + (x - x')^2,   m = 4 r r' / a^2,

    single_layer:  int G dA_y           = int r' K(m) / (pi a) ds'
    double_layer:  int dG/dn_y dA_y     = int [ -n_r' (K(m) + (r'^2 - r^2 - (x - x')^2) E(m) / b^2)
                                                 + n_x' 2 r' (x - x') E(m) / b^2 ] / (2 pi a) ds'

The direct formulation is the one of :mod:`electrosense.bem.system`: with ``n`` out of
the body into the water and ``q = -du/dn``,
``u/2 = single_layer[q] + double_layer[u]`` at every collocation point of
the (smooth) meridian. Elements are arcs of the exact meridian (no faceting
error), constant ``q`` on electrode elements and constant ``u`` on insulator
elements, collocated at their midpoints; the logarithmic singularity of the
ring kernels is integrated by splitting each element at the point nearest the
target with a ``u^2`` substitution on each side, Gauss-Legendre elsewhere.

The meridian is one-dimensional, so it can be graded towards the electrode
edges (where the current density is singular, ~ d^-1/2) far past what a
surface mesh affords: thousands of elements, 1e-7 m at the edges, in about a
second. :func:`converged_conductance` refines such meridians until the
conductance matrix settles and extrapolates (Richardson); it is the
mesh-converged reference the surface BEM is checked against
(``validation/studies/bem_paper.py``) and the source of its free-space
discretisation correction (:mod:`electrosense.bem.edge_correction`).

Conventions as in :mod:`electrosense.bem.conductance`: ``K[i, j]`` is the current (A)
leaving electrode ``i`` into the water when electrode ``j`` is at 1 V and the
others at 0 V, the sensor isolated (currents sum to zero).

Example
-------
>>> from electrosense.meshes import preset
>>> g = meridian_conductance(preset("angels-2"), 1.0)
>>> bool(abs(g.K_S.sum(axis=1)).max() < 1e-12 * abs(g.K_S).max())
True
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.special import ellipe, ellipkm1

from electrosense.bem.conductance import ConductanceMatrix, check_conductivity, isolate
from electrosense.bem.system import contact_impedances
from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.sensor_mesh import SensorProfile, graded_arc_lengths

__all__ = ["MeridianMesh", "mesh_meridian", "ring_single_layer", "ring_double_layer",
           "single_layer", "double_layer", "layer_operators", "meridian_conductance", "converged_conductance"]

_GAUSS_FAR = np.polynomial.legendre.leggauss(6)
_GAUSS_NEAR = np.polynomial.legendre.leggauss(16)


@dataclass(frozen=True)
class MeridianMesh:
    """Elements ``[s_nodes[k], s_nodes[k+1]]`` of the meridian (arc length from the head tip, m).

    ``electrode[k]`` is the electrode number of element ``k`` (0: insulator).
    """

    sensor: SensorDescription
    s_nodes: np.ndarray
    electrode: np.ndarray

    @property
    def n_elements(self) -> int:
        return len(self.electrode)

    @property
    def areas_m2(self) -> np.ndarray:
        """Area of the band each element sweeps around the axis (m^2), exact."""
        profile = SensorProfile(self.sensor)
        u, w = _GAUSS_NEAR
        a, b = self.s_nodes[:-1, None], self.s_nodes[1:, None]
        s = 0.5 * (a + b) + 0.5 * (b - a) * u
        _, r = profile.point(s)
        return 2 * np.pi * np.sum(r * w * 0.5 * (b - a), axis=1)


def mesh_meridian(sensor: SensorDescription, h_far_m: float | None = None, h_edge_m: float | None = None,
                  grading: float = 1.1) -> MeridianMesh:
    """Graded elements along the meridian (every electrode edge on a node).

    Defaults: ``h_far_m = radius / 8`` and ``h_edge_m = 1e-5 h_far_m``.

    Example
    -------
    >>> from electrosense.meshes import preset
    >>> m = mesh_meridian(preset("angels-4"))
    >>> sorted(set(m.electrode.tolist()))
    [0, 1, 2, 3, 4]
    """
    h_far = sensor.radius_m / 8 if h_far_m is None else float(h_far_m)
    h_edge = 1e-5 * h_far if h_edge_m is None else float(h_edge_m)
    if not (h_far > 0 and 0 < h_edge <= h_far and grading > 1):
        raise ValueError(f"mesh_meridian: need h_far_m > 0, 0 < h_edge_m <= h_far_m, grading > 1; "
                         f"got {h_far}, {h_edge}, {grading}")
    s_nodes, _ = graded_arc_lengths(sensor, h_far, h_edge, grading)
    x_mid, _ = SensorProfile(sensor).point(0.5 * (s_nodes[1:] + s_nodes[:-1]))
    electrode = np.zeros(len(s_nodes) - 1, dtype=np.int64)
    for number, e in enumerate(sensor.electrodes, start=1):
        electrode[(x_mid >= e.x_min_m) & (x_mid <= e.x_max_m)] = number
    return MeridianMesh(sensor, np.asarray(s_nodes), electrode)


def _ring_terms(x, r, xs, rs):
    """a, b^2 and the elliptic integrals K(m), E(m) of the ring kernels."""
    dx2 = (x - xs) ** 2
    a2 = (r + rs) ** 2 + dx2
    b2 = (r - rs) ** 2 + dx2
    m1 = b2 / a2                         # 1 - m, without cancellation near the ring itself
    return np.sqrt(a2), b2, ellipkm1(m1), ellipe(1.0 - m1)


def ring_single_layer(x, r, xs, rs):
    """Single layer of a unit-density ring: ``int G r' dphi'`` of the source ring (x', r') at (x, r), 1/m.

    Example
    -------
    >>> # on the axis, 1 m from a ring of radius 1 mm: every point of the ring is sqrt(1 + r'^2) away,
    >>> # so the integral is 2 pi r' / (4 pi sqrt(1 + r'^2)) (a point charge 2 pi r' to 5e-7)
    >>> v = ring_single_layer(1.0, 0.0, 0.0, 1e-3)
    >>> bool(abs(v / (1e-3 / (2 * np.sqrt(1 + 1e-6))) - 1) < 1e-12)
    True
    """
    a, _, K, _ = _ring_terms(x, r, xs, rs)
    return rs * K / (np.pi * a)


def ring_double_layer(x, r, xs, rs, nx, nr):
    """Double layer ``int dG/dn_y r' dphi'`` of the source ring (x', r') with meridian normal (n_x', n_r'), 1/m^2."""
    return _ring_kernels(x, r, xs, rs, nx, nr)[1]


def _ring_kernels(x, r, xs, rs, nx, nr):
    """Single and double layer of the source ring together (one evaluation of K and E)."""
    a, b2, K, E = _ring_terms(x, r, xs, rs)
    dx = x - xs
    single = rs * K / (np.pi * a)
    double = (-nr * (K + (rs**2 - r**2 - dx**2) * E / b2) + nx * 2 * rs * dx * E / b2) / (2 * np.pi * a)
    return single, double


def _element_rules(mesh: MeridianMesh, targets_s: np.ndarray, near_factor: float = 3.0):
    """Quadrature points and weights (ds) for every (target, element) pair.

    Far pairs: 6-point Gauss-Legendre. Near pairs (target within ``near_factor``
    element lengths of the element's midpoint): the element is split at its
    point nearest the target and each side integrated with a ``u^2``
    substitution and 16 points, which integrates the logarithmic singularity.
    Returns the far rule ``(s, w)`` per element, each (elements, 6), and the
    near rule ``(i_target, j_element, s, w)`` per near pair, s and w (pairs, 32).
    """
    profile = SensorProfile(mesh.sensor)
    a, b = mesh.s_nodes[:-1], mesh.s_nodes[1:]
    length = b - a
    mid = 0.5 * (a + b)
    xt, rt = profile.point(targets_s)
    xm, rm = profile.point(mid)
    dist = np.hypot(xt[:, None] - xm[None, :], rt[:, None] - rm[None, :])
    near = dist < near_factor * length[None, :]
    # far: the same rule for every target
    u, w = _GAUSS_FAR
    s_far = mid[:, None] + 0.5 * length[:, None] * u
    w_far = 0.5 * length[:, None] * w
    # near: split at the element's point nearest the target (sampled, then clipped to the element)
    i_near, j_near = np.nonzero(near)
    samples = np.linspace(0.0, 1.0, 65)
    s_samp = a[j_near, None] + length[j_near, None] * samples
    xs, rs = profile.point(s_samp)
    k = np.argmin((xs - xt[i_near, None]) ** 2 + (rs - rt[i_near, None]) ** 2, axis=1)
    s_split = s_samp[np.arange(len(k)), k]
    on_self = targets_s[i_near] >= a[j_near]
    on_self &= targets_s[i_near] <= b[j_near]
    s_split = np.where(on_self, targets_s[i_near], s_split)
    un, wn = _GAUSS_NEAR
    t = 0.5 * (un + 1.0)                 # Gauss points on [0, 1]
    left = (s_split - a[j_near])[:, None]
    right = (b[j_near] - s_split)[:, None]
    s_near = np.concatenate([s_split[:, None] - left * t**2, s_split[:, None] + right * t**2], axis=1)
    w_near = np.concatenate([left * 2 * t * 0.5 * wn, right * 2 * t * 0.5 * wn], axis=1)
    return (s_far, w_far), (i_near, j_near, s_near, w_near)


def layer_operators(mesh: MeridianMesh, wall_x_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Collocation matrices ``(V, D)`` of :func:`single_layer` and :func:`double_layer` at the element midpoints,
    in one pass: what :func:`meridian_conductance` assembles, to pass it again for other contact impedances
    (the assembly is most of a solve: 2.7 of 2.9 s on 2 150 elements).

    ``wall_x_m``: an insulating plane wall ``x = wall_x_m`` across the axis (the water on the sensor's side), taken
    in by its image (:mod:`electrosense.bem.image_plane`): every source ring ``(x', r')`` with meridian normal
    ``(n_x', n_r')`` has a twin at ``(2 wall_x_m - x', r')`` with normal ``(-n_x', n_r')``, still a problem of
    revolution: a sensor facing a wall square on, with no mesh of the wall, the exact reference of a sensor
    tip millimetres from a wall. The twins are at least twice the gap away, integrated by 16-point Gauss-Legendre
    on every element.
    """
    profile = SensorProfile(mesh.sensor)
    mid = 0.5 * (mesh.s_nodes[:-1] + mesh.s_nodes[1:])
    xt, rt = profile.point(mid)
    (s_far, w_far), (i_near, j_near, s_near, w_near) = _element_rules(mesh, mid)

    def kernels(x, r, s):
        return _ring_kernels(x, r, *profile.point(s), *profile.normal(s))

    n = mesh.n_elements
    V, D = np.empty((n, n)), np.empty((n, n))
    for start in range(0, n, 256):          # far rule in blocks of targets (bounded memory)
        rows = slice(start, min(n, start + 256))
        single, double = kernels(xt[rows, None, None], rt[rows, None, None], s_far[None])
        V[rows] = np.sum(single * w_far[None], axis=2)
        D[rows] = np.sum(double * w_far[None], axis=2)
    single, double = kernels(xt[i_near, None], rt[i_near, None], s_near)
    V[i_near, j_near] = np.sum(single * w_near, axis=1)
    D[i_near, j_near] = np.sum(double * w_near, axis=1)
    if wall_x_m is not None:
        _check_wall(mesh.sensor, wall_x_m)
        u, w = _GAUSS_NEAR
        a, b = mesh.s_nodes[:-1, None], mesh.s_nodes[1:, None]
        s_img, w_img = 0.5 * (a + b) + 0.5 * (b - a) * u, 0.5 * (b - a) * w
        (xs, rs), (nx, nr) = profile.point(s_img), profile.normal(s_img)
        for start in range(0, n, 128):
            rows = slice(start, min(n, start + 128))
            single, double = _ring_kernels(xt[rows, None, None], rt[rows, None, None], 2 * wall_x_m - xs, rs, -nx, nr)
            V[rows] += np.sum(single * w_img[None], axis=2)
            D[rows] += np.sum(double * w_img[None], axis=2)
    return V, D


def _check_wall(sensor: SensorDescription, wall_x_m: float) -> None:
    """Refuse a wall that cuts the sensor or stands behind it (the water must lie on the sensor's side)."""
    tip_x_m = 0.5 * float(sensor.length_m)          # the head tip (arc length 0)
    if not wall_x_m > tip_x_m:
        raise ValueError(f"wall_x_m = {wall_x_m} m: the wall must stand beyond the sensor's head tip "
                         f"(x = {tip_x_m:.6g} m), the water on the sensor's side")


def single_layer(mesh: MeridianMesh) -> np.ndarray:
    """``V[i, j] = int_{element j} G(x_i, y) dA_y`` (m), collocation at element midpoints."""
    return layer_operators(mesh)[0]


def double_layer(mesh: MeridianMesh) -> np.ndarray:
    """``D[i, j] = int_{element j} dG/dn_y(x_i, y) dA_y`` (dimensionless), normals into the water."""
    return layer_operators(mesh)[1]


def meridian_conductance(sensor: SensorDescription, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                         mesh: MeridianMesh | None = None, grounded: bool = False,
                         operators: tuple[np.ndarray, np.ndarray] | None = None,
                         wall_x_m: float | None = None) -> ConductanceMatrix:
    """Conductance matrix of a sensor of revolution alone in unbounded water, by ring elements.

    Parameters
    ----------
    sensor : SensorDescription
    sigma_S_per_m : float
        Conductivity of the water (S/m).
    contact_impedance_ohm_m2 : float or sequence, optional
        Contact impedance of the electrodes (one value or one per electrode).
    mesh : MeridianMesh, optional
        Default :func:`mesh_meridian` (angels-4: 1 400 elements, within 1e-4 of converged, a second).
    grounded : bool
        Return the matrix with the far field held at 0 V (a sphere electrode
        alone gives ``4 pi sigma a``) instead of the isolated sensor's.
    operators : (V, D), optional
        :func:`layer_operators` of ``mesh``, assembled once for several solves.
    wall_x_m : float, optional
        An insulating plane wall across the axis at ``x = wall_x_m`` beyond the head tip (the sensor's frame),
        by its image (:func:`layer_operators`); not with ``operators`` (they hold a wall or none already).

    Returns
    -------
    ConductanceMatrix
        ``info`` holds the element count and seconds.
    """
    t0 = time.perf_counter()
    sigma_S_per_m = check_conductivity(sigma_S_per_m)
    mesh = mesh_meridian(sensor) if mesh is None else mesh
    n = len(sensor.electrodes)
    z = contact_impedances(contact_impedance_ohm_m2, n)
    if operators is not None and wall_x_m is not None:
        raise ValueError("meridian_conductance: give wall_x_m to layer_operators, not beside operators "
                         "assembled already (they hold a wall or none)")
    V, D = layer_operators(mesh, wall_x_m) if operators is None else operators
    on_electrode = mesh.electrode > 0
    zs = np.where(on_electrode, z[np.maximum(mesh.electrode, 1) - 1] * sigma_S_per_m, 0.0)
    # u/2 - D u - V q = 0; on electrodes u = V_k - z sigma q, on insulators u is the unknown
    A = np.where(on_electrode[None, :], -V + zs[None, :] * (D - 0.5 * np.eye(len(zs))), 0.5 * np.eye(len(zs)) - D)
    patterns = (mesh.electrode[:, None] == np.arange(1, n + 1)[None, :]).astype(float)   # element potential per 1 V
    b = D @ patterns - 0.5 * patterns
    solution = np.linalg.solve(A, b)
    flux = np.where(on_electrode[:, None], solution, 0.0) * sigma_S_per_m * mesh.areas_m2[:, None]
    C = patterns.T @ flux
    C = 0.5 * (C + C.T)
    K = C if grounded else isolate(C)
    return ConductanceMatrix(K, sensor.emitter, float(sigma_S_per_m),
                             info=dict(model="bem-meridian", elements=mesh.n_elements,
                                       seconds=time.perf_counter() - t0))


def converged_conductance(sensor: SensorDescription, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                          refinements=(1, 2, 4), h_far_m: float | None = None, grading: float = 1.1,
                          wall_x_m: float | None = None):
    """Mesh-converged conductance matrix by Richardson extrapolation over refined meridians.

    The meridian family ``h_far / d``, ``h_edge = 1e-5 h_far / d``,
    ``grading = 1 + (grading - 1) / d`` for ``d`` in ``refinements`` refines every
    element by ``d``; the observed order ``p`` of every entry comes from the
    three finest and the limit is ``K_d + (K_d - K_{d/2}) / (2^p - 1)``. ``wall_x_m``: an insulating wall
    across the axis beyond the head tip, as in :func:`meridian_conductance`.

    Returns
    -------
    limit : ConductanceMatrix
        ``info`` holds the observed orders, the finest mesh's departure from the
        limit (an error estimate) and the element counts.
    """
    t0 = time.perf_counter()
    h_far = sensor.radius_m / 4 if h_far_m is None else float(h_far_m)
    values, counts = [], []
    for d in refinements:
        mesh = mesh_meridian(sensor, h_far / d, 1e-5 * h_far / d, 1 + (grading - 1) / d)
        values.append(meridian_conductance(sensor, sigma_S_per_m, contact_impedance_ohm_m2, mesh,
                                           wall_x_m=wall_x_m).K_S)
        counts.append(mesh.n_elements)
    K0, K1, K2 = values[-3:]
    ratio = refinements[-1] / refinements[-2]
    d1, d2 = K1 - K0, K2 - K1
    scale = np.abs(K2).max()
    settled = np.abs(d2) < 1e-9 * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(settled, np.inf, np.log(np.abs(d1 / d2)) / np.log(ratio))
    monotone = np.sign(d1) == np.sign(d2)
    p_use = np.where(monotone & np.isfinite(p) & (p > 0.5), p, 1.0)   # non-monotone: a cautious order 1
    limit = np.where(settled, K2, K2 + d2 / (ratio**p_use - 1))
    limit = 0.5 * (limit + np.swapaxes(limit, -1, -2))
    departure = float(np.max(np.abs(K2 - limit)) / scale)
    return ConductanceMatrix(limit, sensor.emitter, float(sigma_S_per_m),
                             info=dict(model="bem-meridian-richardson", elements=counts,
                                       observed_order=np.where(np.isfinite(p), p, np.nan).tolist(),
                                       finest_departure=departure, seconds=time.perf_counter() - t0))
