"""A sensor's free-space response to a slowly varying outside field, region by region, by reciprocity.

Near walls and objects the sensor sits in the field ``phi_r`` that its
environment returns to it. To first order the currents change by
(reciprocity: Green's second identity between ``phi_r`` and the isolated
unit solution ``u_k`` of electrode ``k``, ``q_k = du_k/dn`` with ``n`` out of
the water, ``phi_r`` harmonic in and around the sensor body)::

    dI_k = sigma * int_surface ( u_k dphi_r/dn - phi_r q_k ) dS .

Cut the surface along the axis into regions, one per whole electrode (every
surface point goes to the electrode whose centre is nearest along the axis),
and expand ``phi_r`` to first order about each region's centre ``c_m`` on the
axis: ``phi_r ~ phi_r(c_m) + grad phi_r(c_m) . (x - c_m)``. Then::

    dI_k = sum_m Z[k, m] phi_r(c_m) + sum_m G[k, m, :] . grad phi_r(c_m),
    Z[k, m]    = -sigma sum_{t in m} a_t q_k,t                  (= -sum of K over electrode m's sectors)
    G[k, m, :] =  sigma sum_{t in m} a_t (u_k,t n_t - q_k,t (x_t - c_m)).

``Z`` is the poly-spherical model's own term (an electrode's potential
lowered by the returned potential); ``G`` is what a sensor with sectors adds:
the transverse components of the field across the body at *every* region
(a sector's current also answers to the field at the emitter, through its
coupling to it), and the axial ones. ``G`` comes from the free-space surface
solution at no extra solve; summed over the regions it is the response to a
uniform field, checked against the incident-field solve of
:func:`electrosense.bem.symmetric.solve_symmetric` (``tests/test_sector_bem.py``). The
sector PSM (:mod:`electrosense.psm.sectors`) evaluates ``phi_r`` and its gradient at the
region centres from the images and objects.

Example
-------
>>> from electrosense.meshes import preset
>>> s = preset("angels-2").with_sectors({1: 2}, gap_m=0.002)
>>> r = free_space_response(s, 1.0, edge_length_m=0.012)
>>> G = r.gradient_response.sum(axis=1)        # the response to a uniform gradient of the potential
>>> bool(G[0, 1] < 0 < G[1, 1])   # sector 1 faces +y: a potential rising towards +y drives current into it
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix
from electrosense.bem.edge_correction import free_space_correction
from electrosense.bem.symmetric import solve_symmetric

__all__ = ["FreeSpaceResponse", "free_space_response", "region_responses"]


@dataclass
class FreeSpaceResponse:
    """A sensor alone in unbounded water: K, and its response to an outside field region by region."""

    conductance: ConductanceMatrix
    region_centres_m: np.ndarray       # (M, 3) sensor frame, on the axis: the whole electrodes' centres
    region_of_electrode: np.ndarray    # (n,) region (0-based) of each numbered electrode
    potential_response: np.ndarray     # Z (n, M), S
    gradient_response: np.ndarray      # G (n, M, 3), S m: current per unit gradient of the potential (V/m)
    uniform_field_A_per_V_per_m: np.ndarray   # (n, 2): current per unit field along y, z (incident-field solve)


def region_responses(solution, sensor):
    """(centres (M, 3), region of each triangle (F,), Z (n, M), G (n, M, 3)) of a free-space surface solution."""
    wb = solution.boundary
    tri = wb.triangles_m
    centroid = tri.mean(axis=1)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / (2 * area[:, None])          # out of the water (the boundary's winding)
    centres = np.zeros((len(sensor.electrodes), 3))
    centres[:, 0] = [e.x_centre_m for e in sensor.electrodes]
    region = np.argmin(np.abs(centroid[:, 0, None] - centres[None, :, 0]), axis=1)
    n, M = sensor.n_electrodes, len(centres)
    sigma = solution.sigma_S_per_m
    Z = np.zeros((n, M))
    G = np.zeros((n, M, 3))
    for k in range(n):
        V = np.zeros(n)
        V[k] = 1.0
        u, q = solution.surface(V)
        Z[k] = -sigma * np.bincount(region, area * q, minlength=M)
        integrand = area[:, None] * (u[:, None] * normal - q[:, None] * (centroid - centres[region]))
        for d in range(3):
            G[k, :, d] = sigma * np.bincount(region, integrand[:, d], minlength=M)
    return centres, region, Z, G


def free_space_response(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2=None, edge_length_m=None,
                        edge_correction: bool = True, **mesh_options) -> FreeSpaceResponse:
    """K with the edge correction, and the region responses ``Z``, ``G`` of the surface solution.

    ``Z`` and ``G`` are the surface solution's (not edge-corrected), like the
    BEM's own K in a tank beyond the free-space correction.
    """
    from electrosense.meshes.sector_mesh import symmetry_order
    from electrosense.meshes.sensor_mesh import mesh_sensor

    mesh = mesh_sensor(sensor, edge_length_m=edge_length_m, **mesh_options)
    wb = WaterBoundary.from_meshes(mesh, emitter=sensor.emitter, allow_touching=sensor.sectors_touch)
    centroids = wb.triangles_m.mean(axis=1)
    incident = -centroids[:, 1:3]            # unit fields along +y and +z: potentials -y and -z
    solution = solve_symmetric(wb, sigma_S_per_m, contact_impedance_ohm_m2, sensor.emitter,
                               order=symmetry_order(sensor), incident_potential_V=incident)
    grounded = np.asarray(solution.info.pop("incident_currents_A"))
    c = solution.currents_A.sum(axis=1)     # every electrode at 1 V, grounded
    uniform = grounded - np.outer(c, grounded.sum(axis=0)) / c.sum()   # isolated
    centres, region, Z, G = region_responses(solution, sensor)
    if edge_correction:
        solution.K_correction_S = free_space_correction(sensor, sigma_S_per_m, contact_impedance_ohm_m2, mesh,
                                                        surface_K_S=solution.K_surface_S,
                                                        mesh_options=dict(mesh_options, edge_length_m=edge_length_m))
    region_of = np.array([sensor.sector_of(k)[0] for k in range(1, sensor.n_electrodes + 1)])
    return FreeSpaceResponse(solution.conductance, centres, region_of, Z, G, uniform)
