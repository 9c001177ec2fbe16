"""Disc electrode flush in an insulating plane: the BEM against Newman's R = 1/(4 sigma a), and its order.

The water fills a hemisphere of radius ``b`` (default 20 a); the flat face is
an insulating plane with the disc electrode (radius ``a``) at its centre, the
curved face is the return electrode. The exact resistance is
``1/(4 sigma a) - 1/(2 pi sigma b)`` (:func:`electrosense.bem.closed_forms.newman_disc_resistance_ohm`,
error O((a/b)^4)). The plane is meshed by the same code as a tank's floor
with a disc electrode (:func:`electrosense.meshes.cylinder_tank_mesh.mesh_plane_with_discs`,
graded towards the rim), so the figure is the default tank electrode mesh's
accuracy. It prints the relative error at the default mesh and under
refinement (rim edge length and far edge length divided by a factor), with
the observed order in the number of triangles.

Run: ``esense study disc_electrode [--factors 1 1.41 2] [-o DIR]``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.closed_forms import newman_disc_resistance_ohm
from electrosense.bem.solve import solve
from electrosense.meshes.cylinder_tank_mesh import mesh_plane_with_discs
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.surface_electrodes import (
    DEFAULT_EDGE_FRACTION,
    DEFAULT_ELECTRODE_GRADING,
    DiscElectrode,
    electrode_size_function,
)
from electrosense.meshes.tank_mesh import mesh_convex_polygon


def hemisphere_cell(radius_m: float, return_radius_m: float, edge_fraction: float = DEFAULT_EDGE_FRACTION,
                    grading: float = DEFAULT_ELECTRODE_GRADING, h_far_m: float | None = None) -> LabelledMesh:
    """Water hemisphere: floor z = 0 with the disc (electrode 1) at the origin, the dome is electrode 2."""
    a, b = float(radius_m), float(return_radius_m)
    h_far = b / 4 if h_far_m is None else h_far_m
    size = electrode_size_function([DiscElectrode((0, 0, 0), a)], h_far, edge_fraction, grading)
    n_rim = max(24, int(np.ceil(2 * np.pi * b / h_far)))
    phi = 2 * np.pi * np.arange(n_rim) / n_rim
    ring = np.stack([b * np.cos(phi), b * np.sin(phi), np.zeros(n_rim)], axis=1)
    pts, tri, lab = mesh_plane_with_discs(ring[:, :2], [((0.0, 0.0), a, edge_fraction * a, 1)],
                                          lambda q: size(np.c_[q, np.zeros(len(q))]))
    floor = LabelledMesh(np.c_[pts, np.zeros(len(pts))], tri[:, ::-1], lab, None, ("floor",))

    def dome(q):  # polar angle proportional to the distance from the centre of the (u, v) disc
        rho = np.linalg.norm(q, axis=1)
        theta = 0.5 * np.pi * rho / b
        ph = np.arctan2(q[:, 1], q[:, 0])
        return b * np.stack([np.sin(theta) * np.cos(ph), np.sin(theta) * np.sin(ph), np.cos(theta)], axis=1)

    pts, tri = mesh_convex_polygon(ring[:, :2], lambda q: np.full(len(q), h_far))
    verts = np.concatenate([ring, dome(pts[n_rim:])])
    cap = LabelledMesh(verts, tri, np.full(len(tri), 2), None, ("dome",))
    m = concatenate([floor, cap])
    v, inv = np.unique(m.vertices_m, axis=0, return_inverse=True)
    return LabelledMesh(v, inv.ravel()[m.faces], m.electrode, m.region, m.region_names)


def disc_error(factor: float = 1.0, radius_m: float = 0.01, ratio: float = 20.0, sigma_S_per_m: float = 1.0) -> dict:
    """Relative error of the BEM's disc resistance at the default mesh divided by ``factor``."""
    t0 = time.perf_counter()
    cell = hemisphere_cell(radius_m, ratio * radius_m, DEFAULT_EDGE_FRACTION / factor,
                           DEFAULT_ELECTRODE_GRADING / factor ** 0.5, ratio * radius_m / (4 * factor))
    wb = WaterBoundary.from_meshes(None, tank=cell)
    sol = solve(wb, sigma_S_per_m)
    R = 1.0 / sol.conductance.K_S[0, 0]
    ref = newman_disc_resistance_ohm(radius_m, sigma_S_per_m, ratio * radius_m)
    return {"factor": factor, "triangles": cell.n_triangles, "R_ohm": R, "R_exact_ohm": ref,
            "relative_error": R / ref - 1, "seconds": time.perf_counter() - t0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="esense study disc_electrode", description=__doc__.splitlines()[0])
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 1.41, 2.0])
    ap.add_argument("-o", "--out", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = [disc_error(f) for f in args.factors]
    print(f"{'factor':>7} {'triangles':>9} {'R BEM (ohm)':>12} {'R exact':>10} {'rel. error':>11} {'s':>6}")
    for r in rows:
        print(f"{r['factor']:7.2f} {r['triangles']:9d} {r['R_ohm']:12.5f} {r['R_exact_ohm']:10.5f} "
              f"{r['relative_error']:+11.2e} {r['seconds']:6.1f}")
    orders = []
    for r0, r1 in zip(rows, rows[1:]):
        e0, e1 = abs(r0["relative_error"]), abs(r1["relative_error"])
        orders.append(float(np.log(e0 / e1) / np.log(r1["triangles"] / r0["triangles"])))
    print("observed order in the number of triangles N (error ~ N^-p):", [round(p, 2) for p in orders])
    print("target at the default mesh (factor 1): |error| <= 3e-3")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "disc_electrode.json").write_text(json.dumps({"rows": rows, "orders": orders}, indent=1))


if __name__ == "__main__":
    main()
