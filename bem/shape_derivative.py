"""How K changes when an insulating boundary moves: the shape derivative, from the solution already computed.

With electrode ``j`` at 1 V and the others at 0 V, the unit solution ``u_j``
is harmonic in the water, fixed on the electrodes and has no normal flux on
every insulating boundary (tank walls, floor, free surface, the sensor's
body). The conductance matrix is the mutual energy of the unit solutions,

    K_ij = sigma * integral over the water of grad u_i . grad u_j dV.

Move an insulating boundary Gamma outward (the water grows) by ``V_n`` per
unit of a parameter ``theta``. The electrodes stay, so the change of each
``u`` vanishes on them, and the volume terms of the derivative integrate by
parts to boundary terms that vanish (the change is zero on the electrodes,
the flux is zero on Gamma). What remains is the Hadamard formula (e.g.
Sokolowski & Zolesio, *Introduction to Shape Optimization*, 1992, sec. 2.31)::

    dK_ij / dtheta = sigma * integral over Gamma of V_n  grad_s u_i . grad_s u_j  dS,

where ``grad_s`` is the gradient along the boundary (the whole gradient
there: the normal derivative is zero). Every entry of K follows from the
unit solutions on the moved boundary alone; no new solve. A wall that comes
closer (``V_n < 0``) lowers every diagonal entry: less water.

The collocation BEM gives the potential at each face's centroid. The
tangential gradient is reconstructed by weighted least squares over the
faces that share a vertex with the face and lie in nearly its plane (a
local quadratic: exact for one), as a sparse linear operator built once per
mesh (:func:`surface_gradient_operator`). Where a source is close (the
sensor a centimetre or two from a wall, the tank's faces about as large),
the potential varies faster than the faces resolve, and the reconstruction
alone is 6-12 % off (first order in the face size). There the source's own
part is taken exactly: at a point of a flat insulating face the
representation formula has no self term, so the potential is twice the
layers of every other surface, ``u(x) = 2 (S q - D u)_sensor(x) + 2 (...)_rest(x)``;
the sensor's part and its tangential gradient are evaluated at the faces
near it (:func:`layer_part`), and only the smooth rest is reconstructed.

Example
-------
A potential linear along a flat boundary has its gradient everywhere:

>>> import numpy as np
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.meshes.tank_mesh import mesh_tank
>>> mesh = mesh_tank(Tank((1.0, 1.0, 1.0)), 0.25)
>>> op = surface_gradient_operator(mesh.triangles_m)
>>> c = mesh.triangles_m.mean(axis=1)
>>> floor = np.isclose(c[:, 2], -0.5)
>>> g = op.gradient((2.0 * c[:, 0] - c[:, 1])[:, None])[floor, 0]
>>> bool(np.allclose(g, [2.0, -1.0, 0.0]))
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["SurfaceGradientOperator", "surface_gradient_operator", "layer_part", "shape_derivatives"]

#: faces whose normals differ by more than this (degrees) are not neighbours in the gradient's least squares:
#: the edges and corners of a box are not smoothed across
NEIGHBOUR_MAX_ANGLE_DEG = 25.0


@dataclass
class SurfaceGradientOperator:
    """Sparse maps from face values (F,) to the components of their tangential gradient (F,) each."""

    components: tuple  # three (F, F) sparse matrices: d/dx, d/dy, d/dz along the boundary
    areas_m2: np.ndarray  # (F,)
    centroids_m: np.ndarray  # (F, 3)
    tangents: np.ndarray  # (F, 2, 3) two unit tangents of each face
    neighbours: sp.csr_matrix  # (F, F) the faces each face's least squares uses

    def gradient(self, values: np.ndarray, part: tuple | None = None) -> np.ndarray:
        """(F, k, 3) tangential gradient of face values (F, k).

        ``part``: ``(faces, values, gradients)`` of a known part of the values at some faces ((q,), (q, k),
        (q, k, 3)); at those faces whose neighbours are all among them the gradient is the part's own plus the
        reconstruction of the rest.
        """
        v = np.asarray(values, float).reshape(len(self.areas_m2), -1)
        g = np.stack([G @ v for G in self.components], axis=-1)
        if part is None:
            return g
        faces, pv, pg = part
        faces = np.asarray(faces, int)
        inside = np.zeros(len(v), bool)
        inside[faces] = True
        rest = v.copy()
        rest[faces] -= pv
        # faces whose every neighbour has the part: the split is consistent there
        interior = inside & (np.asarray(self.neighbours @ (~inside).astype(float)).ravel() == 0)
        at = np.flatnonzero(interior[faces])
        g_rest = np.stack([G[faces[at]] @ rest for G in self.components], axis=-1)
        g[faces[at]] = g_rest + pg[at]
        return g


def _tangent_bases(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (F, 3) each, orthogonal to the unit ``normals`` and to each other."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


def surface_gradient_operator(triangles_m: np.ndarray, max_angle_deg: float = NEIGHBOUR_MAX_ANGLE_DEG
                              ) -> SurfaceGradientOperator:
    """The least-squares tangential gradient of face-centroid values on a triangulated surface (module doc).

    Neighbours of a face: the faces sharing a vertex with it whose normals are within ``max_angle_deg`` of its
    own; offsets projected on its plane, weights 1 / distance^2.
    """
    T = np.asarray(triangles_m, float)
    F = len(T)
    c = T.mean(axis=1)
    cross = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    n = cross / double_area[:, None]
    # vertices merged by position (the surface's faces share them), face-vertex incidence, faces sharing a vertex
    _, vid = np.unique(np.round(T.reshape(-1, 3), 12), axis=0, return_inverse=True)
    vid = vid.ravel()
    M = sp.csr_matrix((np.ones(3 * F), (np.repeat(np.arange(F), 3), vid)), shape=(F, vid.max() + 1))
    A = (M @ M.T).tocoo()
    i, j = A.row, A.col
    keep = (i != j) & (np.einsum("pk,pk->p", n[i], n[j]) > np.cos(np.radians(max_angle_deg)))
    i, j = i[keep], j[keep]
    t1, t2 = _tangent_bases(n)
    d = c[j] - c[i]
    a = np.stack([np.einsum("pk,pk->p", d, t1[i]), np.einsum("pk,pk->p", d, t2[i])], axis=1)  # (E, 2)
    w = 1.0 / np.maximum(np.einsum("pk,pk->p", a, a), 1e-30)
    # u_j - u_i = g . a + (1/2) a^T H a: a quadratic along the boundary, the gradient exact for it
    basis = np.column_stack([a, 0.5 * a[:, 0] ** 2, a[:, 0] * a[:, 1], 0.5 * a[:, 1] ** 2])  # (E, 5)
    k = basis.shape[1]
    count = np.bincount(i, minlength=F)
    quadratic = count[i] >= k + 2   # enough neighbours for the quadratic; else the plane alone
    basis[~quadratic, 2:] = 0.0
    N = np.zeros((F, k, k))
    np.add.at(N, i, w[:, None, None] * basis[:, :, None] * basis[:, None, :])
    for m in range(2, k):   # faces fitted by a plane: the curvature rows are identity (decoupled, zero)
        N[count < k + 2, m, m] = 1.0
    scale = np.sqrt(np.maximum(np.einsum("fkk->fk", N), 1e-300))   # equilibrated, then inverted
    Ninv = np.linalg.pinv(N / scale[:, :, None] / scale[:, None, :], rcond=1e-10) / scale[:, :, None] / scale[:, None, :]
    coef = np.einsum("pab,pb->pa", Ninv[i][:, :2], w[:, None] * basis)  # (E, 2): g_i = sum_j coef_ij (u_j - u_i)
    components = []
    for axis in range(3):
        cx = coef[:, 0] * t1[i, axis] + coef[:, 1] * t2[i, axis]
        G = sp.csr_matrix((cx, (i, j)), shape=(F, F))
        G = G - sp.diags(np.asarray(G.sum(axis=1)).ravel())
        components.append(G.tocsr())
    neighbours = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(F, F))
    return SurfaceGradientOperator(tuple(components), 0.5 * double_area, c, np.stack([t1, t2], axis=1), neighbours)


def layer_part(points_m: np.ndarray, tangents: np.ndarray, triangles, u: np.ndarray, q: np.ndarray,
               step_m: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """Twice the potential of the layers ``(u, q)`` (T, k) of ``triangles`` at boundary points (P, 3) of flat
    faces, and its gradient along their two unit ``tangents`` (P, 2, 3) (differences of the exact layers over
    ``step_m``, far below the distance to the sources): the part of the boundary potential those triangles make
    (module doc). Returns (P, k), (P, k, 3).
    """
    from electrosense.bem.operators import layer_matrices

    x = np.asarray(points_m, float).reshape(-1, 3)
    t = np.asarray(tangents, float).reshape(-1, 2, 3)
    shifted = np.concatenate([x, x + step_m * t[:, 0], x + step_m * t[:, 1]])
    S, D = layer_matrices(shifted, triangles)
    val = 2.0 * (S @ q - D @ u)  # (3 P, k)
    P = len(x)
    v0 = val[:P]
    d = (val[P:].reshape(2, P, -1) - v0[None]) / step_m  # (2, P, k): along each tangent
    grad = np.einsum("apk,pac->pkc", d, t)
    return v0, grad


def shape_derivatives(op: SurfaceGradientOperator, potentials: np.ndarray, normal_velocities,
                      sigma_S_per_m: float = 1.0, part: tuple | None = None) -> np.ndarray:
    """(k, n, n) dK / dtheta_k (S per unit of theta_k) for boundary faces moving outward (out of the water) by
    ``normal_velocities`` (k, F; dense or sparse) per unit of each theta_k, from the unit solutions' potentials
    (F, n) on those faces (module doc; ``part`` as in :meth:`SurfaceGradientOperator.gradient`).

    Moving the sensor by ``d`` in a tank that holds nothing else is moving every wall by ``-d`` as seen from it:
    the velocities ``-n . d`` (and ``-(z x (c - p)) . n`` for a turn about the vertical through ``p``) give the
    BEM's pose derivatives from the same solution.
    """
    g = op.gradient(potentials, part)  # (F, n, 3)
    n = g.shape[1]
    pair = np.einsum("fia,fja->fij", g, g).reshape(len(g), n * n)
    V = normal_velocities
    weighted = V.multiply(op.areas_m2[None, :]).tocsr() if sp.issparse(V) else np.asarray(V, float) * op.areas_m2
    return sigma_S_per_m * np.asarray(weighted @ pair).reshape(-1, n, n)
