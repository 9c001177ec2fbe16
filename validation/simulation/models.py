"""From a model name to conductance matrices: the one door to the BEM and the PSM.

Every command that needs model currents for many poses (sweeps, comparisons
with bench logs, the virtual bench, the gap diagnosis) comes through here, so
that ``"bem"`` and ``"psm"`` mean the same thing everywhere:

* ``"bem"``: the boundary-element reference, :class:`electrosense.bem.PoseSweep`, which
  builds the pose-invariant blocks once and then solves pose after pose;
* ``"psm"``: the poly-spherical model, :func:`electrosense.psm.conductance`, vectorised
  over poses. Without an explicit model the PSM is calibrated against the
  free-space BEM conductance of the same sensor (:func:`calibrated_psm`), once:
  the calibration is cached on disk, keyed by the sensor description, the BEM
  edge length and the code version. A sensor with sectors gets the sector PSM
  (:mod:`electrosense.psm.sectors`, :func:`calibrated_sector_psm`), calibrated and cached the same way.

The split into :func:`pose_evaluator` (the pose-invariant part, a picklable
object with ``.conductance(poses)``) and :func:`simulate` (evaluate it) is what
lets :mod:`electrosense.validation.simulation.sweep` ship the expensive part to dask workers once.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.validation.simulation.models import simulate
>>> poses = np.array([[x, 0.0, 0.0, 0.0] for x in np.linspace(-0.3, 0.3, 5)])
>>> C = simulate("psm", preset("angels-4"), poses, Tank((1.0, 1.0, 1.0)), 0.0354)  # doctest: +SKIP
>>> C.resistance_ohm.shape  # doctest: +SKIP
(5, 3)
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from electrosense.bem.block_cache import cache_root, source_digest
from electrosense.bem.conductance import ConductanceMatrix
from electrosense.meshes.pose import poses_array as _poses_from_any
from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.tank import Tank

__all__ = [
    "MODELS",
    "EvaluatorCache",
    "ModelError",
    "PSMEvaluator",
    "SectorPSMEvaluator",
    "EachPoseOnItsOwnMesh",
    "PartialConductance",
    "WhereItReaches",
    "poses_reached",
    "calibrated_sector_psm",
    "pose_evaluator",
    "simulate",
    "calibrated_psm",
    "free_space_bem",
    "calibration_layout",
    "psm_cache_dir",
    "code_version",
    "poses_array",
]

#: The model names understood by :func:`simulate` (``"map"``: a tank map, :mod:`.tank_map`, given as
#: ``tank_map=FILE``).
MODELS = ("bem", "psm", "map")

#: Keyword arguments of the calibration BEM that a PSM run accepts.
_PSM_CALIBRATION_OPTIONS = ("edge_length_m",)


class ModelError(ValueError):
    """A model name, model file or model option that cannot be used as given."""


def poses_array(poses) -> np.ndarray:
    """Poses as a (P, 4) float array; a (P, 4) array passes without a copy per row.

    :func:`electrosense.meshes.pose.poses_array` for anything else (Pose objects, rows).
    """
    if isinstance(poses, np.ndarray) and poses.ndim == 2 and poses.shape[1] == 4:
        poses = np.asarray(poses, dtype=float)
        if not np.all(np.isfinite(poses)):
            raise ValueError("poses contain non-finite values")
        return poses
    return _poses_from_any(poses)


# --------------------------------------------------------------------------- version
def code_version(refresh: bool = False) -> str:
    """``"electrosense <version> src <hash>"``: the package version and a hash of the model sources.

    The hash covers every ``.py`` file of :mod:`meshes`, :mod:`bem` and
    :mod:`psm` (:func:`electrosense.bem.block_cache.source_digest`), so that an edited solver (an editable install keeps its version
    number) is told apart from the one that filled a cache or a sweep store.
    It is computed once per process; ``refresh=True`` reads the files again.
    """
    if refresh:
        _code_version.cache_clear()
        source_digest.cache_clear()
    return _code_version()


@functools.lru_cache(maxsize=1)
def _code_version() -> str:
    try:
        from importlib.metadata import version

        package_version = version("electrosense")
    except Exception:  # not installed: running from a checkout
        package_version = "unknown"
    return f"electrosense {package_version} src {source_digest(MODEL_PACKAGES)[:12]}"


#: the packages whose sources :func:`code_version` hashes
MODEL_PACKAGES = ("meshes", "bem", "psm")


# ------------------------------------------------------------------------------- PSM
@dataclass(frozen=True)
class PSMEvaluator:
    """The PSM at fixed scene and water: ``.conductance(poses)`` for any batch of poses.

    A small picklable object (the model's radii and centres plus the scene),
    the PSM counterpart of :class:`electrosense.bem.PoseSweep`. ``image_shells`` fixes the
    number of shells of the complete image series (see :meth:`for_poses`),
    so that a sweep cut into chunks gives exactly what one call would.
    """

    model: object  # psm.PolySphericalModel
    sigma_S_per_m: float
    tank: Tank | None = None
    objects: tuple = ()
    images: str = "complete"
    contact_impedance_ohm_m2: object = None
    sensor: SensorDescription | None = None
    image_shells: int | None = None
    info: dict = field(default_factory=dict, compare=False)

    def conductance(self, poses, progress: bool = False) -> ConductanceMatrix:
        """Conductance matrices of batch shape (P,) at the poses (P, 4) (``progress`` is ignored: one vectorised call)."""
        from electrosense.psm import conductance

        return conductance(
            self.model,
            poses_array(poses),
            self.sigma_S_per_m,
            tank=self.tank,
            images=self.images,
            objects=tuple(self.objects),
            contact_impedance_ohm_m2=self.contact_impedance_ohm_m2,
            sensor=self.sensor,
            image_shells=self.image_shells,
        )

    def for_poses(self, poses, max_probes: int = 24) -> "PSMEvaluator":
        """The same evaluator with the image shell count settled once for this whole set of poses.

        The complete series adds shells until K stops changing on probe poses;
        the probes are taken here from the whole set (the poses nearest each
        boundary plus an even spread), not chunk by chunk.
        """
        if self.tank is None or self.images != "complete" or self.image_shells is not None:
            return self
        from electrosense.psm.conductance import sphere_centres_m

        poses = poses_array(poses)
        if len(poses) > max_probes:
            X = sphere_centres_m(self.model, poses)  # (P, n, 3)
            gap = self.tank.distance_to_boundary_m(X).min(axis=1)  # (P, 6)
            nearest = set(np.argmin(gap, axis=0).tolist())
            spread = np.linspace(0, len(poses) - 1, max(1, max_probes - len(nearest))).astype(int)
            poses = poses[sorted(nearest | set(spread.tolist()))]
        shells = self.conductance(poses).info.get("image_shells")
        return replace(self, image_shells=None if shells is None else int(shells))


@dataclass
class SectorPSMEvaluator:
    """The sector PSM (:mod:`electrosense.psm.sectors`) at many poses: ``.conductance(poses)``, like :class:`PSMEvaluator`."""

    model: object  # psm.sectors.SectorModel
    sigma_S_per_m: float
    tank: Tank | None = None
    objects: tuple = ()
    images: str = "complete"
    contact_impedance_ohm_m2: object = None
    info: dict = field(default_factory=dict, compare=False)

    def conductance(self, poses, progress: bool = False) -> ConductanceMatrix:
        """Conductance matrices of batch shape (P,) at the poses (P, 4)."""
        from electrosense.psm.sectors import sector_conductance

        return sector_conductance(self.model, poses_array(poses), self.sigma_S_per_m, tank=self.tank,
                                  images=self.images, objects=tuple(self.objects),
                                  contact_impedance_ohm_m2=self.contact_impedance_ohm_m2)

    def for_poses(self, poses, max_probes: int = 24) -> "SectorPSMEvaluator":
        return self   # a fixed image series: every chunk is computed as one call would


def calibrated_sector_psm(sensor: SensorDescription, edge_length_m: float | None = None, cache: bool = True):
    """The sector PSM of ``sensor`` (:class:`electrosense.psm.sectors.SectorModel`) from its free-space BEM, computed once.

    :func:`electrosense.bem.lateral.free_space_response` at 1 S/m (K with the edge correction,
    the regions' responses), cached as JSON in :func:`psm_cache_dir`, keyed as :func:`calibrated_psm`.
    """
    from electrosense.psm.sectors import SectorModel

    key = _psm_cache_key(sensor, edge_length_m, {"sectors": True})

    def compute():
        from electrosense.bem.lateral import free_space_response

        response = free_space_response(sensor, 1.0, edge_length_m=edge_length_m)
        return SectorModel.from_response(response, sensor.emitter,
                                         info={"sensor": sensor.to_dict(), "bem_edge_length_m": edge_length_m,
                                               "triangles": response.conductance.info.get("triangles")},
                                         sensor=sensor)

    return _cached_model(psm_cache_dir() / f"psm-sectors-{key}.json", SectorModel.load, compute, cache)


def _cached_model(path: Path, load, compute, cache: bool):
    """``load(path)`` if the cache holds it, else ``compute()``, written to ``path`` atomically."""
    if cache and path.exists():
        try:
            return load(path)
        except Exception:  # a damaged cache entry is recomputed, never trusted
            path.unlink(missing_ok=True)
    model = compute()
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.json")
        model.save(partial)
        os.replace(partial, path)  # atomic: a concurrent reader sees all or nothing
    return model


def _load_sector_psm(psm_model, sensor: SensorDescription):
    from electrosense.psm.sectors import SectorModel

    if isinstance(psm_model, (str, os.PathLike)):
        path = Path(psm_model)
        if not path.exists():
            raise ModelError(f"PSM file {path} does not exist")
        try:
            psm_model = SectorModel.load(path)
        except (ValueError, KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ModelError(f"{path}: not a sector PSM file ({exc}); sensor {sensor.name!r} has sectors") from None
    if not isinstance(psm_model, SectorModel):
        raise ModelError(f"sensor {sensor.name!r} has sectors: its PSM is a sector model (psm.sectors), "
                         f"got a {type(psm_model).__name__}")
    if psm_model.n != sensor.n_electrodes or psm_model.emitter != sensor.emitter:
        raise ModelError(f"the sector PSM has {psm_model.n} electrodes and emitter {psm_model.emitter}; the sensor "
                         f"{sensor.name!r} has {sensor.n_electrodes} and emitter {sensor.emitter}")
    return psm_model


def psm_cache_dir() -> Path:
    """Folder of the cached PSM calibrations: ``psm`` under the one cache root
    (:func:`electrosense.bem.block_cache.cache_root`)."""
    return cache_root() / "psm"


def _psm_cache_key(sensor: SensorDescription, edge_length_m, layout: dict) -> str:
    geometry = {k: v for k, v in sensor.to_dict().items() if k not in ("name", "notes")}
    description = {
        "sensor": geometry,
        "bem_edge_length_m": edge_length_m,
        "layout": layout,
        "code_version": code_version(),
    }
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:20]


def calibration_layout(sensor: SensorDescription, symmetric: bool | None = None) -> dict:
    """The least constrained PSM layout that a free-space S determines: ``{"symmetric", "fix_length_m"}``.

    S has m (m + 1) / 2 distinct entries (m receivers); the free layout of n
    spheres has 2n - 1 parameters, the paper's symmetric one about half as
    many. When even that is too many (n = 2: one conductance), the distance
    between the outer sphere centres is fixed to the sensor's length, as the
    paper does for its two-electrode sensor (L = 20 cm).

    >>> calibration_layout(preset("angels-4"))  # doctest: +SKIP
    {'symmetric': True, 'fix_length_m': None}
    """
    from electrosense.psm.calibration import Layout

    n = sensor.n_electrodes
    n_data = (n - 1) * n // 2
    candidates = [(False, None), (True, None), (True, float(sensor.length_m))]
    if symmetric is not None:
        candidates = [c for c in candidates if c[0] == bool(symmetric)] + [(bool(symmetric), float(sensor.length_m))]
    for sym, fix in candidates:
        if Layout(n, sym, fix).n_free <= n_data:
            return {"symmetric": sym, "fix_length_m": fix}
    raise ModelError(f"no PSM layout of {n} spheres is determined by the {n_data} conductance(s) of {sensor.name!r}")


def free_space_bem(sensor: SensorDescription, edge_length_m: float | None = None):
    """The sensor's BEM conductance matrix alone in unbounded water at 1 S/m (with the edge correction of
    :mod:`electrosense.bem.edge_correction`): the reference every PSM calibration of the package fits."""
    from electrosense.bem import conductance_matrix
    from electrosense.meshes.scene import Scene

    return conductance_matrix(Scene(sensor), 1.0, edge_length_m=edge_length_m)


def calibrated_psm(
    sensor: SensorDescription,
    edge_length_m: float | None = None,
    symmetric: bool | None = None,
    cache: bool = True,
):
    """A PSM calibrated against the free-space BEM conductance of ``sensor``, computed once.

    The reference is :func:`free_space_bem` in
    unbounded water (the PSM's geometry does not depend on the conductivity);
    :func:`electrosense.psm.calibrate` fits the spheres to it in the layout of
    :func:`calibration_layout`. The result is cached as a PSM JSON file in
    :func:`psm_cache_dir`, keyed by the sensor description, the BEM edge
    length, the layout and :func:`code_version`.

    Parameters
    ----------
    sensor : SensorDescription
    edge_length_m : float, optional
        Edge length of the calibration BEM mesh (``None``: the mesher's default).
    symmetric : bool, optional
        Force (True) or forbid (False) the paper's symmetry constraints;
        default: the least constrained layout the data determine.
    cache : bool
        Read and write the on-disk cache (``False``: always recompute).

    Returns
    -------
    psm.PolySphericalModel, or for a sensor with sectors :class:`electrosense.psm.sectors.SectorModel`
    (:func:`calibrated_sector_psm`)
    """
    from electrosense.psm import PolySphericalModel

    if sensor.has_sectors:   # no spheres describe sectors: the sector model (its calibration has no layout)
        return calibrated_sector_psm(sensor, edge_length_m, cache=cache)
    layout = calibration_layout(sensor, symmetric)
    # the file name is a hash only: a sensor's name is a user's label, never part of a path
    path = psm_cache_dir() / f"psm-{_psm_cache_key(sensor, edge_length_m, layout)}.json"

    def compute():
        from electrosense.psm.calibration import calibrate

        reference = free_space_bem(sensor, edge_length_m)
        return calibrate(reference, layout["symmetric"], layout["fix_length_m"], sensor=sensor).model

    return _cached_model(path, PolySphericalModel.load, compute, cache)


def _load_psm(psm_model):
    """A PSM from a model object or a path to its JSON file."""
    if isinstance(psm_model, (str, os.PathLike)):
        from electrosense.psm import PolySphericalModel

        path = Path(psm_model)
        if not path.exists():
            raise ModelError(f"PSM file {path} does not exist")
        try:
            return PolySphericalModel.load(path)
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ModelError(f"{path}: not a PSM model file ({exc})") from None
    return psm_model


def _check_psm_matches(model, sensor: SensorDescription) -> None:
    n = len(np.asarray(model.radii_m))
    if n != sensor.n_electrodes:
        raise ModelError(
            f"the PSM has {n} spheres but the sensor {sensor.name!r} has {sensor.n_electrodes} electrodes"
        )
    if int(model.emitter) != sensor.emitter:
        raise ModelError(f"the PSM's emitter is electrode {model.emitter}, the sensor's is {sensor.emitter}")


# ------------------------------------------------------------------------- the door
def pose_evaluator(
    model: str,
    sensor: SensorDescription,
    tank: Tank | None,
    sigma_S_per_m: float,
    objects=(),
    psm_model=None,
    contact_impedance_ohm_m2=None,
    images: str = "complete",
    poses=None,
    prepare: bool = True,
    skip_blocked: bool = False,
    **bem_options,
):
    """The pose-invariant part of a model run: an object with ``.conductance(poses) -> ConductanceMatrix``.

    For ``"bem"`` a :class:`electrosense.bem.PoseSweep` (sensor and tank blocks assembled
    once); for ``"psm"`` a :class:`PSMEvaluator`. Both are picklable, so a
    sweep can scatter them to dask workers once and send only poses after.

    Parameters are those of :func:`simulate`; ``poses`` (optional) are the
    poses it will be used for. Give them for a sweep cut into chunks: the
    BEM then grades one tank mesh towards all of them and assembles its
    pose-invariant blocks at once, the PSM settles its image series over all
    of them, so that every chunk, on any worker, is computed exactly as one
    call over all poses would. ``prepare=False`` leaves the BEM's blocks to
    its first call (for a single call over all poses).

    ``skip_blocked=True`` (with ``poses``): where the model does not reach a pose (:func:`poses_reached`:
    the sensor beyond a wall or into an object, the PSM's spheres across a wall, a map's gap), the pose is
    left out rather than refused: the evaluator is prepared for the poses it reaches and wrapped in
    :class:`WhereItReaches`, whose matrices are NaN at the others.
    """
    if skip_blocked and poses is not None:
        common = dict(contact_impedance_ohm_m2=contact_impedance_ohm_m2, images=images, **bem_options)
        P = poses_array(poses)
        # the BEM's reach is the scene's; the PSM's and a map's are their own (the PSM's calibration is cached)
        probe = None if model == "bem" else pose_evaluator(model, sensor, tank, sigma_S_per_m, objects, psm_model,
                                                           poses=None, **common)
        reached, why = poses_reached(probe, sensor, tank, objects, P)
        if not reached.any():
            raise ModelError(f"the model reaches none of the {len(P)} poses: {why}")
        inner = pose_evaluator(model, sensor, tank, sigma_S_per_m, objects, psm_model, poses=P[reached],
                               prepare=prepare, **common)
        return WhereItReaches(inner, sensor, tank, tuple(objects), int(np.count_nonzero(~reached)), why)
    if not (np.isfinite(sigma_S_per_m) and sigma_S_per_m > 0):
        raise ModelError(f"sigma_S_per_m must be a positive conductivity, got {sigma_S_per_m}")
    code_version()  # pin the model code's version now, as it is loaded; dask workers must run the same
    objects = tuple(objects)
    if model == "bem":
        if psm_model is not None:
            raise ModelError("psm_model is given but the model is 'bem'")
        from electrosense.bem import PoseSweep

        options = dict(bem_options)
        if contact_impedance_ohm_m2 is not None:
            options["contact_impedance_ohm_m2"] = contact_impedance_ohm_m2
        images_m = options.pop("image_faces_within_m", None)
        if images_m is not None and tank is not None:   # each pose its own tank mesh, its near faces images
            return EachPoseOnItsOwnMesh(PoseSweep(sensor, tank=tank, objects=objects, sigma_S_per_m=sigma_S_per_m,
                                                  **options), float(images_m))
        if poses is not None and tank is not None and "focus_m" not in options:
            from electrosense.meshes.scene_mesh import trajectory_focus_m

            # one tank mesh for the whole sweep, graded towards every pose (not the first chunk's)
            options["focus_m"] = trajectory_focus_m(sensor, poses_array(poses))
        sweep = PoseSweep(sensor, tank=tank, objects=objects, sigma_S_per_m=sigma_S_per_m, **options)
        if poses is not None and prepare:
            # build the environment's blocks here, once, before the sweep is shipped to workers
            sweep.conductance(poses_array(poses)[:1])
        return sweep
    if model == "psm":
        unknown = sorted(set(bem_options) - set(_PSM_CALIBRATION_OPTIONS))
        if unknown:
            raise ModelError(
                f"option(s) {', '.join(unknown)} are BEM options; with the PSM only "
                f"{', '.join(_PSM_CALIBRATION_OPTIONS)} (of the calibration BEM) is used"
            )
        calibrated = psm_model is None
        if sensor.has_sectors:   # the contact impedance in series, as the PSM's
            if calibrated:
                psm_model = calibrated_sector_psm(sensor, bem_options.get("edge_length_m"))
            info = {"model": "psm-sectors", "images": images, "calibrated_on_free_space_bem": calibrated}
            return SectorPSMEvaluator(_load_sector_psm(psm_model, sensor), float(sigma_S_per_m), tank, objects,
                                      images, contact_impedance_ohm_m2, info=info)
        if calibrated:
            psm_model = calibrated_psm(sensor, edge_length_m=bem_options.get("edge_length_m"))
        psm_model = _load_psm(psm_model)
        _check_psm_matches(psm_model, sensor)
        info = {"model": "psm", "images": images, "calibrated_on_free_space_bem": calibrated}
        evaluator = PSMEvaluator(psm_model, float(sigma_S_per_m), tank, objects, images,
                                 contact_impedance_ohm_m2, sensor, info=info)
        return evaluator if poses is None else evaluator.for_poses(poses)
    if model == "map":
        from electrosense.validation.simulation.tank_map import MapEvaluator, load_tank_map

        if bem_options.get("tank_map") is None:
            raise ModelError("the model 'map' needs a map file (tank_map=..., `--map FILE`)")
        tank_map = bem_options["tank_map"]
        tank_map = load_tank_map(tank_map) if isinstance(tank_map, (str, os.PathLike)) else tank_map
        from electrosense.validation.simulation.tank_map import same_scene, scene_record

        if tank_map.sensor.to_dict() != sensor.to_dict() or \
                not same_scene(tank_map.tank, tank_map.objects, tank, tuple(objects)):
            raise ModelError(f"the map is of {tank_map.sensor.name} in {scene_record(tank_map.tank)['tank']} with "
                             f"{len(tank_map.objects)} fixed object(s); the run asks for {sensor.name} in "
                             f"{None if tank is None else scene_record(tank)['tank']} with {len(tuple(objects))}")
        if poses is not None:   # refused here, before any store or worker exists, with the pose's index
            inside, why = tank_map.covers(poses_array(poses))
            if not inside.all():
                raise ModelError(why)
        return MapEvaluator(tank_map, float(sigma_S_per_m))
    raise ModelError(f"unknown model {model!r}; known: {', '.join(MODELS)}")


def poses_reached(evaluator, sensor: SensorDescription, tank: Tank | None, objects, poses) -> tuple[np.ndarray, str]:
    """(P,) bool: the poses ``evaluator``'s model computes, and why the first other is not reached ("" if all are).

    Every model needs the sensor in the water and clear of every object (:func:`electrosense.meshes.scene_mesh.
    scene_problems`, what the BEM checks at each pose; ``evaluator`` ``None`` is the BEM); the PSM also its
    spheres in the water and clear of the objects (:func:`electrosense.psm.conductance.placement_fits`); a
    tank map its depth and the wall gap it was built for (:meth:`TankMap.covers`).

    >>> from electrosense.meshes.sensor import preset
    >>> poses = np.array([[0.0, 0, 0, 0], [0.45, 0, 0, 0]])
    >>> poses_reached(None, preset("angels-2"), Tank((1.0, 1.0, 1.0)), (), poses)[0].tolist()
    [True, False]
    """
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.scene_mesh import object_problems, scene_problems

    P = poses_array(poses)
    objects = tuple(objects)
    inner = getattr(evaluator, "tank_map", None)
    if inner is not None:
        return inner.covers(P)
    scene_wide = object_problems(tank, objects)     # objects out of the water or touching: no pose is reached
    if scene_wide:
        return np.zeros(len(P), bool), "; ".join(scene_wide)
    # the scene's exact check (a scalar minimisation per object) only where a vectorised bound cannot clear the pose
    reached = _surely_clear(sensor, tank, objects, P)
    why = ""
    for i in np.flatnonzero(~reached):
        problems = scene_problems(Scene(sensor, Pose.from_array(P[i]), tank, objects))
        reached[i] = not problems
        why = why or (f"pose {i}: {'; '.join(problems)}" if problems else "")
    if isinstance(evaluator, PSMEvaluator):
        from electrosense.psm.conductance import placement_fits

        spheres = placement_fits(evaluator.model, P, tank, objects)
        if not why and not spheres.all():
            i = int(np.argmin(spheres))
            why = f"pose {i}: a sphere of the PSM crosses a wall or touches an object (its wall images do not hold there)"
        reached &= spheres
    return reached, why


def _surely_clear(sensor: SensorDescription, tank: Tank | None, objects: tuple, poses: np.ndarray,
                  n_axis: int = 17) -> np.ndarray:
    """(P,) bool: poses whose sensor is certainly inside the water and clear of every object: its gaps sampled
    along its axis (:func:`~electrosense.validation.simulation.tank_map.boundary_gaps_m`) above half the samples'
    spacing."""
    from electrosense.validation.simulation.tank_map import boundary_gaps_m

    gaps = boundary_gaps_m(sensor, tank, poses, objects, n_axis)
    half = 0.5 * sensor.length_m - sensor.radius_m
    return np.min(gaps, axis=1, initial=np.inf) > half / (n_axis - 1) + 1e-6


@dataclass(frozen=True)
class EachPoseOnItsOwnMesh:
    """The BEM with each pose on a tank mesh graded to it alone and the tank's flat faces within ``within_m`` of the
    sensor image planes (``image_faces_within_m=`` of :func:`pose_evaluator`; :func:`electrosense.validation.
    simulation.tank_map.each_on_its_own_tank_mesh`): the walls beside the sensor exact, where one mesh for a whole
    path is 0.03-0.06 % off within 15 mm of a wall; as a tank map's BEM poses, at a tank mesh per pose."""

    sweep: object   # electrosense.bem.PoseSweep
    within_m: float

    @property
    def sigma_S_per_m(self) -> float:
        return self.sweep.sigma_S_per_m

    def conductance(self, poses, progress: bool = False) -> ConductanceMatrix:
        from electrosense.validation.simulation.tank_map import each_on_its_own_tank_mesh

        K = each_on_its_own_tank_mesh(self.sweep, poses_array(poses), self.within_m)
        return ConductanceMatrix(K, self.sweep.sensor.emitter, float(self.sigma_S_per_m),
                                 {"model": "bem", "tank_mesh": "each pose its own", "image_faces_within_m":
                                  self.within_m})


@dataclass(frozen=True)
class WhereItReaches:
    """A model's evaluator at the poses it reaches; NaN matrices at the others (``esense sweep --skip-blocked``).

    ``.conductance(poses)`` gives an object with ``K_S`` (P, n, n; NaN rows where the model does not reach the
    pose: :func:`poses_reached`), ``emitter``, ``sigma_S_per_m`` and ``info``: what a sweep's runner stores. It
    is not a :class:`ConductanceMatrix`, which holds finite matrices only.
    """

    evaluator: object
    sensor: SensorDescription
    tank: Tank | None
    objects: tuple = ()
    n_blocked: int = 0      #: poses of the sweep it was made for that the model does not reach
    why: str = ""           #: why the first of them is not reached

    @property
    def sigma_S_per_m(self) -> float:
        return self.evaluator.sigma_S_per_m

    def conductance(self, poses, progress: bool = False) -> "PartialConductance":
        P = poses_array(poses)
        reached, _ = poses_reached(self.evaluator, self.sensor, self.tank, self.objects, P)
        n = self.sensor.n_electrodes
        K = np.full((len(P), n, n), np.nan)
        info = {}
        if reached.any():
            C = self.evaluator.conductance(P[reached])
            K[reached], info = C.K_S, C.info
        return PartialConductance(K, self.sensor.emitter, float(self.sigma_S_per_m), info)


@dataclass(frozen=True)
class PartialConductance:
    """Conductance matrices (P, n, n) with NaN rows where a model did not reach the pose (:class:`WhereItReaches`)."""

    K_S: np.ndarray
    emitter: int
    sigma_S_per_m: float
    info: dict = field(default_factory=dict, compare=False)


def simulate(
    model: str,
    sensor: SensorDescription,
    poses,
    tank: Tank | None,
    sigma_S_per_m: float,
    objects=(),
    psm_model=None,
    contact_impedance_ohm_m2=None,
    images: str = "complete",
    progress: bool = False,
    **bem_options,
) -> ConductanceMatrix:
    """Conductance matrices of ``sensor`` at many poses, by the BEM or the PSM.

    Parameters
    ----------
    model : {"bem", "psm"}
    sensor : SensorDescription
    poses : array (P, 4) or sequence of Pose
        Sensor centre (x_m, y_m, z_m) and yaw_rad in the tank frame.
    tank : Tank or None
        ``None`` for unbounded water.
    sigma_S_per_m : float
        Conductivity of the water.
    objects : sequence of Sphere/Box/Cylinder
    psm_model : PolySphericalModel or path to its JSON, optional
        The PSM to use; ``None`` calibrates one on the sensor's free-space BEM
        (:func:`calibrated_psm`, cached). Only for ``"psm"``.
    contact_impedance_ohm_m2 : float or array (n,), optional
    images : {"complete", "paper8", "none"}
        The PSM's tank images (ignored by the BEM, which meshes the tank).
    progress : bool
        Progress bar (BEM pose sweeps).
    **bem_options
        Passed to :class:`electrosense.bem.PoseSweep` (e.g. ``edge_length_m``); with the
        PSM only ``edge_length_m`` of the calibration BEM.

    Returns
    -------
    ConductanceMatrix of batch shape (P,)

    Example
    -------
    >>> C = simulate("psm", preset("angels-2"), [[0, 0, 0, 0]], None, 0.0354)  # doctest: +SKIP
    >>> C.batch_shape  # doctest: +SKIP
    (1,)
    """
    poses = poses_array(poses)
    evaluator = pose_evaluator(
        model, sensor, tank, sigma_S_per_m, objects, psm_model, contact_impedance_ohm_m2, images,
        poses=poses, prepare=False, **bem_options,
    )
    return evaluator.conductance(poses, progress=progress)


class EvaluatorCache:
    """Pose evaluators (BEM pose sweeps, PSMs) shared by the logs of one scene.

    The BEM's pose-invariant blocks (sensor and tank matrices) are built once
    per (model, sensor, tank, conductivity, objects) and reused for every log
    of that scene.
    """

    def __init__(self, psm_model=None, tank_map=None, **bem_options):
        """``psm_model``: a PSM (object or JSON path), a dict sensor name -> PSM, or None (calibrated, cached);
        ``tank_map``: the tank map (object or file) that model ``"map"`` evaluates."""
        self.psm_model = psm_model
        self.tank_map = tank_map
        self.bem_options = bem_options
        self._evaluators = {}

    def _key(self, model, sensor, tank, sigma, objects):
        return (model, json.dumps(sensor.to_dict(), sort_keys=True), repr(tank), float(sigma), repr(tuple(objects)))

    def get(self, model: str, sensor, tank, sigma_S_per_m: float, objects=()):
        key = self._key(model, sensor, tank, sigma_S_per_m, objects)
        if key not in self._evaluators:
            options = dict(self.bem_options)
            psm = None
            if model == "psm":
                psm = self.psm_model
                if isinstance(psm, dict):  # one PSM per sensor name; a sensor without one gets the cached calibration
                    psm = psm.get(sensor.name)
                options = {k: v for k, v in options.items() if k == "edge_length_m"}
            if model == "map":
                options = {"tank_map": self.tank_map}
            self._evaluators[key] = pose_evaluator(model, sensor, tank, sigma_S_per_m, tuple(objects), psm, **options)
        return self._evaluators[key]
