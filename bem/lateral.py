"""A sensor's free-space response to a slowly varying outside field, region by region, by reciprocity.

Near walls and objects the sensor sits in the field ``phi_r`` that its
environment returns to it. To first order the currents change by
(reciprocity: Green's second identity between ``phi_r`` and the isolated
unit solution ``u_k`` of electrode ``k``, ``q_k = du_k/dn`` with ``n`` out of
the water, ``phi_r`` harmonic in and around the sensor body)::

    dI_k = sigma * int_surface ( u_k dphi_r/dn - phi_r q_k ) dS .

Cut the surface along the axis into regions (:func:`sensor_regions`: each
whole electrode is one, and the insulator between two electrodes is cut into
pieces at most 1.5 radii long), and expand ``phi_r`` to first order about
each region's centre ``c_m`` on the axis: ``phi_r ~ phi_r(c_m) + grad phi_r(c_m) . (x - c_m)``. Then::

    dI_k = sum_m Z[k, m] phi_r(c_m) + sum_m G[k, m, :] . grad phi_r(c_m),
    Z[k, m]    = -sigma sum_{t in m} a_t q_k,t         (= -sum of K over electrode m's sectors; 0 off electrodes)
    G[k, m, :] =  sigma sum_{t in m} a_t (u_k,t n_t - q_k,t (x_t - c_m)).

The same surface integrals give, by the representation formula, the field
the sensor sends out, region by region: a monopole (the region's current)
and a current dipole ``-G[:, m, :]^T V`` (A m). A uniform outside field also
induces dipoles in the insulating body; ``Pi[m]`` (3 x 3, A m per V/m of
gradient) is region ``m``'s share of them, from three incident-field solves
(fields along x, y, z) by the same formula applied to the total solution.

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
>>> # a uniform field along +y: the potential -y, its value at each region's centre and its gradient -e_y
>>> I = -(r.potential_response @ r.region_centres_m) - r.gradient_response.sum(axis=1)
>>> bool(I[0, 1] > 0 > I[1, 1])   # sector 1 faces +y: the field drives current out of it, into sector 2
True
>>> bool(abs(I[0, 1] / r.uniform_field_A_per_V_per_m[0, 1] - 1) < 0.01)   # reciprocity = the incident-field solve
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix
from electrosense.bem.edge_correction import free_space_correction
from electrosense.bem.symmetric import solve_symmetric

__all__ = ["FreeSpaceResponse", "free_space_response", "region_responses", "sensor_regions", "REGION_LENGTH_RADII"]

#: longest insulating region along the axis, in sensor radii
REGION_LENGTH_RADII = 1.5


@dataclass
class FreeSpaceResponse:
    """A sensor alone in unbounded water: K, and its response to an outside field region by region."""

    conductance: ConductanceMatrix
    region_centres_m: np.ndarray       # (M, 3) sensor frame, on the axis
    region_of_electrode: np.ndarray    # (n,) region (0-based) of each numbered electrode
    potential_response: np.ndarray     # Z (n, M), S
    gradient_response: np.ndarray      # G (n, M, 3), S m: current per unit gradient of the potential (V/m)
    dipole_response: np.ndarray        # Pi (M, 3, 3), S m^2: induced current dipole per unit gradient
    uniform_field_A_per_V_per_m: np.ndarray   # (n, 3): current per unit field along x, y, z (incident-field solve)


def sensor_regions(sensor, max_length_m: float | None = None):
    """(region breakpoints along x, head to tail (M + 1,), centres (M, 3), region of each whole electrode (E,)).

    Example
    -------
    >>> from electrosense.meshes import preset
    >>> breaks, centres, of = sensor_regions(preset("angels-2"))
    >>> len(centres), of.tolist()
    (13, [0, 12])
    """
    L = REGION_LENGTH_RADII * sensor.radius_m if max_length_m is None else float(max_length_m)
    half = 0.5 * sensor.length_m
    breaks, of = [half], []
    for e in sensor.electrodes:
        top = breaks[-1]
        if e.x_max_m < top - 1e-12:        # the insulator above this electrode, in pieces
            pieces = int(np.ceil((top - e.x_max_m) / L))
            breaks.extend(top - (top - e.x_max_m) * np.arange(1, pieces + 1) / pieces)
        of.append(len(breaks) - 1)
        breaks.append(e.x_min_m)
    if breaks[-1] > -half + 1e-12:
        pieces = int(np.ceil((breaks[-1] + half) / L))
        breaks.extend(breaks[-1] - (breaks[-1] + half) * np.arange(1, pieces + 1) / pieces)
    breaks = np.array(breaks)
    centres = np.zeros((len(breaks) - 1, 3))
    centres[:, 0] = 0.5 * (breaks[1:] + breaks[:-1])
    for j, e in enumerate(sensor.electrodes):
        centres[of[j], 0] = e.x_centre_m
    return breaks, centres, np.array(of)


def _triangle_regions(sensor, centroid):
    """Regions along the axis (:func:`sensor_regions`), a split electrode's cut by sector (each centred on its
    sector's arc centroid, ``R sin(a) / a`` off the axis, ``a = pi / N``): (breaks, centres (M, 3), region of each
    whole electrode's first sector, region of each triangle)."""
    from electrosense.meshes.sensor import sector_azimuths_rad

    breaks, axial, of = sensor_regions(sensor)
    axial_region = np.clip(np.searchsorted(-breaks, -centroid[:, 0]) - 1, 0, len(axial) - 1)
    centres, first, region = [], {}, np.empty(len(centroid), np.int64)
    phi = np.arctan2(centroid[:, 2], centroid[:, 1])
    split = {of[j]: e for j, e in enumerate(sensor.electrodes) if e.is_split}
    for a, c in enumerate(axial):
        here = axial_region == a
        first[a] = len(centres)
        if a not in split:
            region[here] = len(centres)
            centres.append(c)
            continue
        e = split[a]
        sector_centres, _ = sector_azimuths_rad(e, sensor.radius_m)
        rho = sensor.radius_m * np.sin(np.pi / e.sectors) / (np.pi / e.sectors)
        k = np.round(phi / (2 * np.pi / e.sectors)).astype(np.int64) % e.sectors
        region[here] = len(centres) + k[here]
        for phi_k in sector_centres:
            centres.append(c + [0.0, rho * np.cos(phi_k), rho * np.sin(phi_k)])
    return breaks, np.array(centres), np.array([first[a] for a in of]), region


def _moments(u, q, area, normal, centroid, centres, region, sigma, M):
    """``sigma sum_{t in m} a_t (u_t n_t - q_t (x_t - c_m))`` per region (M, 3)."""
    integrand = area[:, None] * (u[:, None] * normal - q[:, None] * (centroid - centres[region]))
    return sigma * np.stack([np.bincount(region, integrand[:, d], minlength=M) for d in range(3)], axis=-1)


def region_responses(solution, sensor):
    """(centres (M, 3), region of each triangle (F,), Z (n, M), G (n, M, 3), Pi (M, 3, 3) or None) of a
    free-space surface solution (``Pi`` when it carries the three incident fields ``-x, -y, -z``)."""
    wb = solution.boundary
    tri = wb.triangles_m
    centroid = tri.mean(axis=1)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / (2 * area[:, None])          # out of the water (the boundary's winding)
    breaks, centres, of, region = _triangle_regions(sensor, centroid)
    n, M = sensor.n_electrodes, len(centres)
    sigma = solution.sigma_S_per_m
    Z = np.zeros((n, M))
    G = np.zeros((n, M, 3))
    for k in range(n):
        V = np.zeros(n)
        V[k] = 1.0
        u, q = solution.surface(V)
        Z[k] = -sigma * np.bincount(region, area * q, minlength=M)
        G[k] = _moments(u, q, area, normal, centroid, centres, region, sigma, M)
    Pi = None
    x_inc = getattr(solution, "incident_unknowns", None)
    if x_inc is not None and x_inc.shape[1] == 3:
        flux = wb.electrode > 0
        x_all = solution.unknowns.sum(axis=1)                    # every electrode at 1 V, grounded
        c_all = solution.currents_A.sum()
        Pi = np.zeros((M, 3, 3))
        for d in range(3):
            x = x_inc[:, d]
            current = sigma / solution.scale_m * np.sum(area[flux] * x[flux])
            x = x - (current / c_all) * x_all                    # isolated: the sensor floats
            v_float = -current / c_all
            u = np.where(flux, v_float, x)
            q = np.where(flux, x / solution.scale_m, 0.0)
            # the incident field is -x_d: its gradient is -e_d; the sent dipole is -(moments)
            Pi[:, :, d] = _moments(u, q, area, normal, centroid, centres, region, sigma, M)
    return centres, region, Z, G, Pi


def free_space_response(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2=None, edge_length_m=None,
                        edge_correction: bool = True, **mesh_options) -> FreeSpaceResponse:
    """K with the edge correction, and the region responses ``Z``, ``G`` of the surface solution.

    ``Z`` and ``G`` are the surface solution's (not edge-corrected), like the
    BEM's own K in a tank beyond the free-space correction.
    """
    from electrosense.meshes.sector_mesh import block_symmetry
    from electrosense.meshes.sensor_mesh import mesh_sensor

    mesh = mesh_sensor(sensor, edge_length_m=edge_length_m, **mesh_options)
    wb = WaterBoundary.from_meshes(mesh, emitter=sensor.emitter, allow_touching=sensor.sectors_touch)
    centroids = wb.triangles_m.mean(axis=1)
    incident = -centroids                    # unit fields along +x, +y, +z: potentials -x, -y, -z
    order, mirror = block_symmetry(sensor)
    solution = solve_symmetric(wb, sigma_S_per_m, contact_impedance_ohm_m2, sensor.emitter, order=order,
                               incident_potential_V=incident, mirror=mirror)
    grounded = np.asarray(solution.info.pop("incident_currents_A"))
    c = solution.currents_A.sum(axis=1)     # every electrode at 1 V, grounded
    uniform = grounded - np.outer(c, grounded.sum(axis=0)) / c.sum()   # isolated
    centres, region, Z, G, Pi = region_responses(solution, sensor)
    if edge_correction:
        solution.K_correction_S = free_space_correction(sensor, sigma_S_per_m, contact_impedance_ohm_m2, mesh,
                                                        surface_K_S=solution.K_surface_S,
                                                        mesh_options=dict(mesh_options, edge_length_m=edge_length_m))
    first = _triangle_regions(sensor, np.zeros((0, 3)))[2]
    region_of = np.array([first[sensor.sector_of(k)[0]] + sensor.sector_of(k)[1] - 1
                          for k in range(1, sensor.n_electrodes + 1)])
    return FreeSpaceResponse(solution.conductance, centres, region_of, Z, G, Pi, uniform)
