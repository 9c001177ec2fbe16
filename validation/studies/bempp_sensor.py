"""The sensor's mixed boundary-value problem solved with bempp-cl (Galerkin P0, dense LU).

An independent check of our collocation BEM on the sensor, used by
:mod:`electrosense.validation.studies.bem_speed`. The sensor is a closed body in
unbounded water of conductivity ``sigma``; the potential ``u`` is harmonic in
the water, tends to 0 at infinity, equals ``V_k`` on electrode ``k`` and has
zero normal current on the insulator.

Formulation
-----------
Direct boundary integral equation with ``G(x, y) = 1 / (4 pi |x - y|)``, the
normal ``n`` out of the body (into the water, the mesh's orientation) and the
flux ``q = -du/dn`` (the current density leaving into the water over sigma)::

    1/2 u(x) = (V q)(x) + (K u)(x),   V q = int G q dA_y,   K u = int u dG/dn_y dA_y,

for ``x`` on the surface. bempp-cl's double layer uses the grid normal, and
with the outward normal ``K 1 = -1/2`` on a closed surface (checked by
:func:`double_layer_of_one`), which is the sign convention above.

Unknowns: ``q`` on the electrode triangles (P0 restricted to them) and ``u``
on the insulator triangles (P0 restricted to them); ``u = V_k`` is known on
electrode ``k``. Testing with P0 on every triangle (``M`` the mass matrix)
gives the square system::

    [ V_{:,E}   K_{:,I} - 1/2 M_{:,I} ] [q_E; u_I] = (1/2 M_{:,E} - K_{:,E}) u_E.

The grounded conductance is ``C[m, k] = sigma * sum_{faces of m} area * q``
with electrode ``k`` at 1 V and the others at 0 V (the far field at 0 V);
:func:`electrosense.bem.conductance.isolate` floats the sensor.

Example
-------
>>> from electrosense.meshes import preset                                    # doctest: +SKIP
>>> from electrosense.meshes.sensor_mesh import mesh_sensor                   # doctest: +SKIP
>>> s = preset("angels-4")                                       # doctest: +SKIP
>>> g = bempp_conductance(mesh_sensor(s), 1.0, emitter=s.emitter)  # doctest: +SKIP
>>> g.S_S.round(4)                                               # doctest: +SKIP
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["bempp_available", "bempp_grounded_conductance", "bempp_conductance", "double_layer_of_one"]


def bempp_available() -> bool:
    """Whether bempp-cl (module ``bempp_cl``) can be imported."""
    try:
        import bempp_cl.api  # noqa: F401
    except ImportError:
        return False
    return True


def _grid(mesh):
    """bempp grid of a :class:`~meshes.labelled_mesh.LabelledMesh`, element k being face k."""
    import bempp_cl.api as bempp

    grid = bempp.Grid(np.ascontiguousarray(mesh.vertices_m.T, dtype=float),
                      np.ascontiguousarray(mesh.faces.T, dtype=np.uint32))
    if not (np.array_equal(grid.elements.T, mesh.faces) and np.allclose(grid.volumes, mesh.areas_m2)):
        raise RuntimeError("bempp reordered the mesh's elements")
    if np.any(np.sum(grid.normals * mesh.normals, axis=1) <= 0):
        raise RuntimeError("bempp's grid normals disagree with the mesh's")
    return grid


def _p0_space(grid, faces=None):
    """P0 space on all elements, or on the sorted element indices ``faces`` (dof j on ``faces[j]``)."""
    import bempp_cl.api as bempp

    if faces is None:
        return bempp.function_space(grid, "DP", 0)
    space = bempp.function_space(grid, "DP", 0, support_elements=np.asarray(faces, dtype=np.uint32))
    if not np.array_equal(space.local2global[faces, 0], np.arange(len(faces))):
        raise RuntimeError("unexpected dof numbering of a restricted P0 space")
    return space


def double_layer_of_one(mesh) -> np.ndarray:
    """``(K 1)(x)`` averaged over each triangle: -1/2 on a closed surface with outward normals.

    Parameters
    ----------
    mesh : LabelledMesh
        Closed surface; its normals give the orientation of bempp's grid.

    Returns
    -------
    (F,) array
        ``<psi_i, K 1> / area_i`` for the P0 basis ``psi_i`` of each triangle.
    """
    import bempp_cl.api as bempp

    grid = _grid(mesh)
    space = _p0_space(grid)
    K = bempp.as_matrix(bempp.operators.boundary.laplace.double_layer(space, space, space).weak_form())
    return K.sum(axis=1) / grid.volumes


def bempp_grounded_conductance(mesh, sigma_S_per_m: float = 1.0):
    """Grounded conductance matrix of the electrodes of ``mesh`` in unbounded water, with bempp-cl.

    Parameters
    ----------
    mesh : LabelledMesh
        Closed sensor mesh, normals out of the body (into the water),
        ``electrode`` 1..n per face (0: insulator).
    sigma_S_per_m : float
        Conductivity of the water.

    Returns
    -------
    C : (n, n) array
        ``C[m, k]``: current (A) leaving electrode ``m + 1`` into the water
        with electrode ``k + 1`` at 1 V, the other electrodes and infinity at 0 V.
    info : dict
        ``triangles``, ``assembly_s`` (grid, spaces and dense operators) and
        ``solve_s`` (LU factorisation and solves).
    """
    import bempp_cl.api as bempp
    import scipy.linalg

    t0 = time.perf_counter()
    electrode = np.asarray(mesh.electrode)
    n = int(electrode.max())
    on_electrode = np.flatnonzero(electrode > 0)
    on_insulator = np.flatnonzero(electrode == 0)
    grid = _grid(mesh)
    every = _p0_space(grid)
    electrodes = _p0_space(grid, on_electrode)
    laplace = bempp.operators.boundary.laplace
    V_E = bempp.as_matrix(laplace.single_layer(electrodes, every, every).weak_form())     # (F, F_E)
    K = bempp.as_matrix(laplace.double_layer(every, every, every).weak_form())            # (F, F)
    areas = grid.volumes                                   # the P0 mass matrix is diag(areas)
    jump = K                                               # 1/2 M - K, in place
    jump *= -1.0
    jump[np.arange(len(areas)), np.arange(len(areas))] += 0.5 * areas
    u_E = (electrode[on_electrode, None] == np.arange(1, n + 1)).astype(float)           # (F_E, n)
    rhs = jump[:, on_electrode] @ u_E
    A = np.empty_like(jump)
    A[:, on_electrode] = V_E
    A[:, on_insulator] = -jump[:, on_insulator]
    del K, jump, V_E
    t1 = time.perf_counter()
    x = scipy.linalg.lu_solve(scipy.linalg.lu_factor(A, overwrite_a=True, check_finite=False), rhs,
                              check_finite=False)
    t2 = time.perf_counter()
    q = np.zeros((len(areas), n))
    q[on_electrode] = x[on_electrode]
    C = sigma_S_per_m * np.array([[np.sum(areas[electrode == m] * q[electrode == m, k]) for k in range(n)]
                                  for m in range(1, n + 1)])
    return C, {"triangles": len(areas), "assembly_s": t1 - t0, "solve_s": t2 - t1}


def bempp_conductance(mesh, sigma_S_per_m: float = 1.0, emitter: int | None = None):
    """The isolated sensor's conductance matrix with bempp-cl (see :func:`bempp_grounded_conductance`).

    Parameters
    ----------
    mesh : LabelledMesh
        Closed sensor mesh, normals into the water.
    sigma_S_per_m : float
        Conductivity of the water.
    emitter : int, optional
        1-based emitter number (default: the last electrode).

    Returns
    -------
    ConductanceMatrix
        ``K_S = isolate(C)``; ``info`` holds the triangles and timings.
    """
    from electrosense.bem.conductance import ConductanceMatrix, isolate

    C, info = bempp_grounded_conductance(mesh, sigma_S_per_m)
    emitter = C.shape[0] if emitter is None else int(emitter)
    return ConductanceMatrix(isolate(C), emitter, sigma_S_per_m, dict(info, model="bempp-cl P0 Galerkin"))
