"""The poly-spherical model of a sensor whose electrodes are split into sectors.

A sector cannot be a sphere on the axis: what tells it from its neighbours
is on which side of the body it lies. The model keeps the PSM's picture
(the environment returns a potential ``phi_r`` to the sensor, computed from
image sources and object dipoles) and adds what a sector needs: the field
*across* the body, received and sent.

* **Free space.** ``K0``, the sensor's free-space conductance matrix, is
  taken from the BEM (:mod:`electrosense.bem.symmetric`, with its edge correction): the
  sectors of one ring are so close that their mutual conductances are set by
  the gaps between them, which no arrangement of spheres describes.
* **Regions.** The body is cut along the axis into regions, one per whole
  electrode, centred on the axis at ``c_m`` (:mod:`electrosense.bem.lateral`).
* **Receiving.** To first order (reciprocity), the returned potential,
  expanded to first order about each region's centre, changes the currents
  by ``dI = -K0 R phi_r(c) + G . grad phi_r(c)``: ``R`` (n, M) says which
  region each electrode is in, so the first term is the PSM's (an electrode's
  potential lowered by the returned potential), and ``G`` (n, M, 3) is the
  response to the field across and along each region, from the free-space
  BEM solution (a sector takes current in on the side where the potential is
  lower, and answers, more weakly, to the field at the other regions).
* **Sending.** By the same reciprocity, the field the sensor sends out is,
  region by region, a monopole (the region's current) and a current dipole
  ``B_m = -G[:, m, :]^T x`` for effective electrode potentials ``x``: a
  sector's current leaves from one side of the body, and the insulating body
  nearly doubles the dipole that a point source on its surface would have.
  Leaving that dipole out gives about half the lateral signal near a wall.
* **The body's polarisation.** The returned field's gradient also
  polarises the insulating body: each region sends a further dipole
  ``Pi[m] grad phi_r(c_m)`` (from three incident-field BEM solves).
* **Self-consistency, as the PSM.** With ``x = V - R phi_r(c)`` (the
  potentials the electrodes act with), ``I = K0 x + G . grad phi_r(c)``,
  monopoles ``J = R^T I``, dipoles ``B = -G^T x + Pi grad phi_r(c)``, and
  ``[phi_r(c); grad phi_r(c)] = Psi [J; B]`` (``Psi``: the images' and
  objects' reflection between the regions' centres, per pose), the currents
  solve a square linear system of ``2 n + 3 M`` unknowns per pose.

For whole electrodes this is the PSM with an exact free-space part and
dipoles. ``validation/studies/sector_sensor.py`` measures it against the BEM
in the tank (sector currents, and the lateral signal left minus right along
passes 3-10 cm from a wall, and past a sphere).

Gradients and dipoles are taken by central differences of monopole
potentials (:data:`FIELD_STEP_M` apart: relative error ~1e-6 at the
distances that matter).

Example
-------
>>> import numpy as np
>>> K0 = np.array([[2.0, -1, -1], [-1, 2, -1], [-1, -1, 2]]) * 1e-3
>>> m = SectorModel(K0, np.zeros((3, 2, 3)), np.array([[0.1, 0, 0], [-0.1, 0, 0]]), [0, 0, 1], 1.0)
>>> C = sector_conductance(m, [[0.0, 0, 0, 0]], 1.0)
>>> bool(np.allclose(C.K_S[0], K0))
True
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.bem.conductance import ConductanceMatrix, check_conductivity
from electrosense.meshes.pose import poses_array
from electrosense.psm.images import IMAGE_KINDS, image_sources
from electrosense.psm.objects import object_terms

__all__ = ["SectorModel", "sector_conductance", "reflected_potential", "reflection_kernel", "IMAGE_SHELLS",
           "FIELD_STEP_M"]

#: outer shell of the (Richardson-extrapolated) complete image series
IMAGE_SHELLS = 4
#: step of the central differences that give the transverse field (m)
FIELD_STEP_M = 1e-4


@dataclass(frozen=True, eq=False)
class SectorModel:
    """The sector sensor's model: free-space K, regions, and the regions' gradient response.

    Parameters
    ----------
    K0_S : (n, n)
        Free-space conductance matrix at ``sigma_S_per_m`` (S), electrodes numbered as the sensor's.
    gradient_response_S_m : (n, M, 3)
        ``G``: current (A) leaving each electrode per unit gradient (V/m) of the returned potential at each
        region's centre, sensor frame (x, y, z), at ``sigma_S_per_m`` (:mod:`electrosense.bem.lateral`).
    region_centres_m : (M, 3)
        The regions' centres, sensor frame (on the axis).
    region_of_electrode : (n,)
        Region (0-based) of each electrode.
    dipole_response_S_m2 : (M, 3, 3) or None
        ``Pi``: current dipole (A m) each region sends per unit gradient (V/m) of the returned potential at
        its centre (the insulating body's polarisation), sensor frame; None: left out.
    electrode_areas_m2 : (n,) or None
        Wetted area of each electrode, for a contact impedance in series (:mod:`electrosense.psm.contact`).
    body_radius_m : float
        The sensor body's radius: the model's electrodes are "spheres" of that radius at their regions'
        centres where a placement is checked (:attr:`centres_m`, :attr:`radii_m`).
    sigma_S_per_m : float
        The conductivity ``K0`` and ``G`` were computed at (both scale with it).
    emitter : int
        1-based emitter (0: the last electrode).
    info : dict
        Provenance (sensor, mesh, BEM times...).
    """

    K0_S: np.ndarray
    gradient_response_S_m: np.ndarray
    region_centres_m: np.ndarray
    region_of_electrode: np.ndarray
    sigma_S_per_m: float
    emitter: int = 0
    info: dict = field(default_factory=dict)
    dipole_response_S_m2: np.ndarray | None = None
    electrode_areas_m2: np.ndarray | None = None
    body_radius_m: float = 0.0

    def __post_init__(self):
        K0 = np.asarray(self.K0_S, float)
        n = K0.shape[0]
        if K0.shape != (n, n) or n < 2 or not np.all(np.isfinite(K0)):
            raise ValueError(f"K0_S must be a finite square matrix of at least 2 electrodes, got shape {K0.shape}")
        centres = np.asarray(self.region_centres_m, float)
        if centres.ndim != 2 or centres.shape[1] != 3 or not np.all(np.isfinite(centres)):
            raise ValueError(f"region_centres_m must be finite, (M, 3), got {centres.shape}")
        M = centres.shape[0]
        G = np.asarray(self.gradient_response_S_m, float)
        if G.shape != (n, M, 3) or not np.all(np.isfinite(G)):
            raise ValueError(f"gradient_response_S_m must be finite with shape {(n, M, 3)}, got {G.shape}")
        region = np.asarray(self.region_of_electrode, dtype=np.int64).reshape(-1)
        if region.shape != (n,) or region.min() < 0 or region.max() >= M:
            raise ValueError(f"region_of_electrode must give each of the {n} electrodes a region 0..{M - 1}")
        Pi = self.dipole_response_S_m2
        if Pi is not None:
            Pi = np.asarray(Pi, float)
            if Pi.shape != (M, 3, 3) or not np.all(np.isfinite(Pi)):
                raise ValueError(f"dipole_response_S_m2 must be finite with shape {(M, 3, 3)}, got {Pi.shape}")
        areas = self.electrode_areas_m2
        if areas is not None:
            areas = np.asarray(areas, float).reshape(-1)
            if areas.shape != (n,) or not np.all(areas > 0):
                raise ValueError(f"electrode_areas_m2 must be {n} positive areas")
        for name, value in (("K0_S", K0), ("gradient_response_S_m", G), ("region_centres_m", centres),
                            ("region_of_electrode", region), ("dipole_response_S_m2", Pi),
                            ("electrode_areas_m2", areas)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "sigma_S_per_m", check_conductivity(self.sigma_S_per_m))
        emitter = n if self.emitter == 0 else int(self.emitter)
        if not 1 <= emitter <= n:
            raise ValueError(f"emitter {self.emitter} is not an electrode number 1..{n}")
        object.__setattr__(self, "emitter", emitter)

    @property
    def n(self) -> int:
        return self.K0_S.shape[0]

    @property
    def n_regions(self) -> int:
        return self.region_centres_m.shape[0]

    @property
    def centres_m(self) -> np.ndarray:
        """(n, 3) the centre of each electrode's region, sensor frame (as a PSM's sphere centres)."""
        return self.region_centres_m[self.region_of_electrode]

    @property
    def radii_m(self) -> np.ndarray:
        """(n,) the body's radius for every electrode (how far the sensor reaches around a centre)."""
        return np.full(self.n, float(self.body_radius_m))

    @classmethod
    def from_response(cls, response, emitter: int = 0, info: dict | None = None, sensor=None) -> "SectorModel":
        """From a :class:`electrosense.bem.lateral.FreeSpaceResponse` (``sensor``: for the areas and radius)."""
        g = response.conductance
        areas, radius = None, 0.0
        if sensor is not None:
            from electrosense.psm.contact import electrode_areas_m2

            areas, radius = electrode_areas_m2(sensor), float(sensor.radius_m)
        return cls(g.K_S, response.gradient_response, response.region_centres_m, response.region_of_electrode,
                   g.sigma_S_per_m, emitter or g.emitter, dict(info or {}), response.dipole_response, areas, radius)

    # -------------------------------------------------------------------- JSON
    def to_json_dict(self) -> dict:
        return {"model": "psm-sectors",
                "convention": "sensor frame: x along the axis, electrode 1 at the head (+x); SI units; "
                              "gradient response: A per V/m of the returned potential's gradient (x, y, z)",
                "K0_S": self.K0_S.tolist(), "gradient_response_S_m": self.gradient_response_S_m.tolist(),
                "region_centres_m": self.region_centres_m.tolist(),
                "region_of_electrode": self.region_of_electrode.tolist(),
                "dipole_response_S_m2": None if self.dipole_response_S_m2 is None
                else self.dipole_response_S_m2.tolist(),
                "electrode_areas_m2": None if self.electrode_areas_m2 is None else self.electrode_areas_m2.tolist(),
                "body_radius_m": self.body_radius_m,
                "sigma_S_per_m": self.sigma_S_per_m, "emitter": self.emitter, "info": self.info}

    @classmethod
    def from_json_dict(cls, d: dict) -> "SectorModel":
        if not isinstance(d, dict) or d.get("model") != "psm-sectors":
            raise ValueError(f"not a sector model (model = {d.get('model') if isinstance(d, dict) else d!r})")
        try:
            return cls(np.array(d["K0_S"]), np.array(d["gradient_response_S_m"]), np.array(d["region_centres_m"]),
                       np.array(d["region_of_electrode"]), float(d["sigma_S_per_m"]), int(d.get("emitter", 0)),
                       dict(d.get("info", {})),
                       None if d.get("dipole_response_S_m2") is None else np.array(d["dipole_response_S_m2"]),
                       None if d.get("electrode_areas_m2") is None else np.array(d["electrode_areas_m2"]),
                       float(d.get("body_radius_m", 0.0)))
        except KeyError as exc:
            raise ValueError(f"sector model lacks the key {exc}") from None

    def save(self, path) -> None:
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path) -> "SectorModel":
        return cls.from_json_dict(json.loads(Path(path).read_text()))


def _to_tank(points_m: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Sensor-frame points (Q, 3) at every pose (P, 4): (P, Q, 3) in the tank frame."""
    c, s = np.cos(poses[:, 3])[:, None], np.sin(poses[:, 3])[:, None]
    x, y, z = points_m[:, 0][None], points_m[:, 1][None], points_m[:, 2][None]
    return np.stack([c * x - s * y + poses[:, 0, None], s * x + c * y + poses[:, 1, None],
                     z + poses[:, 2, None] + 0 * c], axis=-1)


def reflected_potential(targets_m: np.ndarray, sources_m: np.ndarray, images, obj_centres, obj_coef,
                        include_images: bool = True) -> np.ndarray:
    """``4 pi sigma`` times the potential the environment returns to each target per unit current at each source.

    targets_m (P, T, 3), sources_m (P, S, 3) in the tank frame; images an
    :class:`electrosense.psm.images.ImageSet` (the source itself excluded); objects as in
    :func:`electrosense.psm.objects.object_terms`. Returns (P, T, S): the images'
    ``sum_k w_k / |x - image_k(c)|`` (unless ``include_images`` is False) plus each object's dipole term
    ``-chi b^3 grad G(y_o, x) . grad G(y_o, c)`` (``G`` with the images), as in the PSM's kernel.
    """
    out = np.zeros(targets_m.shape[:2] + sources_m.shape[1:2])
    if len(images) and include_images:
        for p in range(targets_m.shape[0]):
            img = images.signs[None] * sources_m[p][:, None] + images.offsets_m[None]          # (S, K, 3)
            for start in range(0, targets_m.shape[1], 64):
                t = targets_m[p, start:start + 64]
                d = np.linalg.norm(t[:, None, None] - img[None], axis=-1)                     # (T, S, K)
                out[p, start:start + 64] = (1.0 / d) @ images.weights
    def grad(y0, points):   # (P, Q, 3) -> grad_y G(y0, x) at y = y0, (P, Q, 3)
        g = -(y0 - points) / np.linalg.norm(y0 - points, axis=-1, keepdims=True) ** 3
        if len(images):
            im = images.signs[:, None, None] * points[None] + images.offsets_m[:, None, None]   # (K, P, Q, 3)
            dif = y0 - im
            g = g - np.einsum("k,kpqd->pqd", images.weights, dif / np.linalg.norm(dif, axis=-1, keepdims=True) ** 3)
        return g

    for y0, coef in zip(obj_centres, obj_coef):
        out += coef * np.einsum("ptd,psd->pts", grad(y0, targets_m), grad(y0, sources_m))
    return out


def _stencil(centres: np.ndarray) -> np.ndarray:
    """Each centre and its six neighbours +-h along x, y, z: (7 M, 3), centre first, then (+x, -x, +y, ...)."""
    h = FIELD_STEP_M
    steps = np.concatenate([np.zeros((1, 3)), np.repeat(np.eye(3), 2, axis=0) * np.tile([h, -h], 3)[:, None]])
    return (centres[:, None] + steps[None]).reshape(-1, 3)


def _image_kernel(c: np.ndarray, images) -> np.ndarray:
    """The images' part of ``4 pi sigma Psi`` at one pose, tank-frame components: (M, 4, M, 4).

    For targets ``t`` and sources ``s`` at the region centres ``c`` (M, 3), with
    ``d = t - image_k(s)``: potential per unit current ``sum w / r``, its
    gradient ``-sum w d / r^3``; per unit current dipole ``b`` at ``s`` (imaged
    as ``signs * b``): potential ``sum w (signs * b) . d / r^3`` and gradient
    ``sum w [(signs * b) / r^3 - 3 d (d . (signs * b)) / r^5]``.
    """
    from electrosense.psm.kernels import multipole_image_kernel

    out = np.empty((len(c), 4, len(c), 4))
    multipole_image_kernel(np.ascontiguousarray(c, float), np.ascontiguousarray(images.signs, float),
                           np.ascontiguousarray(images.offsets_m, float), np.ascontiguousarray(images.weights, float),
                           out)
    return out


def reflection_kernel(centres_m: np.ndarray, poses: np.ndarray, sigma: float, images, obj_centres, obj_coef):
    """``Psi`` (P, 4M, 4M): [potential; gradient (x, y, z)] the environment returns at each region's centre per
    [unit current; unit current dipole along x, y, z] at each region's centre (sensor-frame components)."""
    M = len(centres_m)
    h = FIELD_STEP_M
    P = len(poses)
    psi = np.zeros((P, M, 4, M, 4))
    c = _to_tank(centres_m, poses)
    if len(images):
        for p in range(P):
            psi[p] = _image_kernel(c[p], images)
    if len(obj_coef):   # objects: central differences of their (imaged) dipole terms
        points = _to_tank(_stencil(centres_m), poses)               # (P, 7M, 3)
        phi = reflected_potential(points, points, images, obj_centres, obj_coef, include_images=False)
        phi = phi.reshape(P, M, 7, M, 7)

        def taylor(a):   # (..., 7) stencil values -> (..., 4): value and central differences along x, y, z
            return np.stack([a[..., 0], (a[..., 1] - a[..., 2]) / (2 * h), (a[..., 3] - a[..., 4]) / (2 * h),
                             (a[..., 5] - a[..., 6]) / (2 * h)], axis=-1)

        obj = taylor(taylor(phi).transpose(0, 1, 3, 4, 2))           # (P, M tgt, M src, 4 src, 4 tgt), sensor frame
        # the stencil is in the sensor frame already: turn the image part's tank-frame components to it below
        obj = obj.transpose(0, 1, 4, 2, 3)
    else:
        obj = 0.0
    # tank -> sensor frame components (rotation about z by the yaw) for the images' part
    cy, sy = np.cos(poses[:, 3]), np.sin(poses[:, 3])
    rot = np.zeros((P, 4, 4))
    rot[:, 0, 0] = rot[:, 3, 3] = 1.0
    rot[:, 1, 1], rot[:, 1, 2], rot[:, 2, 1], rot[:, 2, 2] = cy, sy, -sy, cy      # sensor = R^T tank
    psi = np.einsum("pab,pmbnc,pdc->pmand", rot, psi, rot) + obj
    return psi.reshape(P, 4 * M, 4 * M) / (4 * np.pi * sigma)


def sector_conductance(model: SectorModel, poses, sigma_S_per_m: float, tank=None, images: str = "complete",
                       objects=(), image_shells: int = IMAGE_SHELLS,
                       contact_impedance_ohm_m2=None) -> ConductanceMatrix:
    """Conductance matrices (P, n, n) of the sector model at every pose, as a ConductanceMatrix.

    Parameters as :func:`electrosense.psm.conductance`. A contact impedance is a
    resistance ``z / A`` in series with each electrode, as the PSM's
    (:mod:`electrosense.psm.contact`; it needs the model's ``electrode_areas_m2``):
    ``K' = (1 + K diag(z / A))^-1 K``, on top of whatever ``K0`` carries.
    """
    if images not in IMAGE_KINDS:
        raise ValueError(f"images={images!r}: expected one of {', '.join(IMAGE_KINDS)}")
    sigma = check_conductivity(sigma_S_per_m)
    poses = poses_array(poses)
    scale = sigma / model.sigma_S_per_m
    K0 = model.K0_S * scale
    G = model.gradient_response_S_m.reshape(model.n, -1) * scale            # (n, 3M): region-major, then x, y, z
    imgs = image_sources(tank, "none" if tank is None else images, image_shells)
    obj_centres, _, obj_coef = object_terms(objects, sigma)
    n, M, P = model.n, model.n_regions, len(poses)
    R = np.zeros((n, M))
    R[np.arange(n), model.region_of_electrode] = 1.0
    Pi = np.zeros((M, 3, 3)) if model.dipole_response_S_m2 is None else model.dipole_response_S_m2 * scale
    Pi_full = np.zeros((3 * M, 3 * M))
    for m in range(M):
        Pi_full[3 * m:3 * m + 3, 3 * m:3 * m + 3] = Pi[m]
    # unknowns [x; I; B]: x = V - R phi (effective potentials), I = K0 x + G grad phi (currents),
    # B = -G^T x + Pi grad phi (current dipoles); monopoles J = R^T I; [phi; grad phi] = Psi [J; B]
    potential = np.arange(M) * 4                                          # rows/columns of Psi: potential ...
    gradient = (np.arange(M)[:, None] * 4 + np.arange(1, 4)[None]).ravel()   # ... and gradient, region-major
    K = np.empty((P, n, n))
    eye_n, eye_b = np.eye(n), np.eye(3 * M)
    for start in range(0, P, 8):
        chunk = slice(start, min(P, start + 8))
        psi = reflection_kernel(model.region_centres_m, poses[chunk], sigma, imgs, obj_centres, obj_coef)
        p_J, p_B = psi[:, potential][:, :, potential], psi[:, potential][:, :, gradient]   # potential from J, B
        g_J, g_B = psi[:, gradient][:, :, potential], psi[:, gradient][:, :, gradient]     # gradient from J, B
        c = psi.shape[0]
        rows = [
            [np.broadcast_to(eye_n, (c, n, n)), R @ p_J @ R.T, R @ p_B],
            [np.broadcast_to(-K0, (c, n, n)), eye_n - G @ g_J @ R.T, -G @ g_B],
            [np.broadcast_to(G.T, (c, 3 * M, n)), -Pi_full @ g_J @ R.T, eye_b - Pi_full @ g_B],
        ]
        A = np.concatenate([np.concatenate(r, axis=2) for r in rows], axis=1)
        rhs = np.zeros((c, 2 * n + 3 * M, n))
        rhs[:, :n] = eye_n
        Kp = np.linalg.solve(A, rhs)[:, n:2 * n]
        K[chunk] = 0.5 * (Kp + np.swapaxes(Kp, 1, 2))
    if contact_impedance_ohm_m2 is not None:
        from electrosense.psm.contact import series_contact, series_resistance_ohm

        if model.electrode_areas_m2 is None:
            raise ValueError("a contact impedance needs the sector model's electrode_areas_m2")
        K = series_contact(K, series_resistance_ohm(contact_impedance_ohm_m2, model.electrode_areas_m2))
        K = 0.5 * (K + np.swapaxes(K, 1, 2))
    info = {"model": "psm-sectors", "images": "none" if tank is None else images, "objects": len(obj_coef),
            "image_shells": image_shells if tank is not None and images == "complete" else None}
    return ConductanceMatrix(K, model.emitter, float(sigma), info)
