"""Sensor descriptions: an insulating cylinder with electrodes along its axis.

Conventions (used everywhere in electrosense)
-------------------------------------------
* Sensor frame: the x axis is the sensor axis, origin at the middle of the
  sensor, the head at +x and the tail at -x.
* Electrodes are numbered 1..n in geometric order from the head: electrode 1
  is the head end cap, electrode n the tail end cap.
* The emitter is, by default, the last electrode (the tail), as in the paper
  and in the bench-log spec; every other electrode is a receiver.
* Lengths are in metres.

An electrode is described by its axial extent ``[x_min_m, x_max_m]`` in the
sensor frame. An end cap (``kind="cap"``) is the hemisphere closing the
cylinder at that end plus, where its extent reaches further inwards than the
hemisphere, the adjacent strip of the cylinder; a ring (``kind="ring"``) is a
band of the cylinder. Everything not covered by an electrode is insulating.

Sectors. An electrode may be split around the axis into ``sectors`` equal
angular sectors separated by insulating gaps of ``sector_gap_m`` (measured
along the circumference of the cylinder, radius ``radius_m``; 0 allowed: the
sectors then touch). Sector 1 is centred on the sensor frame's +y side, the
next ones follow in the sense of rotation about +x (from +y towards +z):
sector ``k`` of ``N`` is centred at the azimuth ``(k - 1) 2 pi / N`` measured
from +y towards +z. Every sector is an electrode of its own: the numbers run
head to tail as above, the sectors of a split electrode taking consecutive
numbers (sector 1 first). A split cap's sectors are wedges of constant
angular width that meet at the tip.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> s = preset("angels-4")
>>> s.n_electrodes, s.emitter
(4, 4)
>>> split = s.with_sectors({2: 4, 3: 4}, gap_m=0.002)   # both rings in 4 sectors
>>> split.n_electrodes, split.emitter, split.sector_of(3)
(10, 10, (1, 2))
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

__all__ = ["Electrode", "SensorDescription", "sector_azimuths_rad", "preset", "PRESETS", "load_sensor", "save_sensor"]


@dataclass(frozen=True)
class Electrode:
    """One electrode of a sensor.

    Parameters
    ----------
    kind : {"cap", "ring"}
        ``"cap"``: hemispherical end electrode (optionally with a cylindrical
        collar); ``"ring"``: a band of the cylinder.
    x_min_m, x_max_m : float
        Axial extent in the sensor frame (m). For the head cap ``x_max_m`` is
        the tip (``length_m / 2``); for the tail cap ``x_min_m`` is the tip.
    sectors : int
        Number of equal angular sectors the electrode is split into (1: whole).
    sector_gap_m : float
        Insulating gap between neighbouring sectors along the circumference (m, >= 0).
    """

    kind: str
    x_min_m: float
    x_max_m: float
    sectors: int = 1
    sector_gap_m: float = 0.0

    @property
    def x_centre_m(self) -> float:
        return 0.5 * (self.x_min_m + self.x_max_m)

    @property
    def is_split(self) -> bool:
        return self.sectors > 1


def sector_azimuths_rad(electrode: Electrode, radius_m: float) -> tuple[np.ndarray, float]:
    """Centre azimuths (N,) of an electrode's sectors and their half-width (rad).

    The azimuth is measured from +y towards +z (rotation about +x); sector 1 is
    centred at 0. A whole electrode is one sector of half-width pi.

    Example
    -------
    >>> c, w = sector_azimuths_rad(Electrode("ring", -0.01, 0.01, sectors=4, sector_gap_m=0.0), 0.01)
    >>> np.round(c / np.pi, 3).tolist(), round(w / np.pi, 3)
    ([0.0, 0.5, 1.0, 1.5], 0.25)
    """
    n = int(electrode.sectors)
    centres = 2 * np.pi * np.arange(n) / n
    return centres, float(np.pi / n - 0.5 * electrode.sector_gap_m / radius_m)


@dataclass(frozen=True)
class SensorDescription:
    """An insulating cylinder with hemispherical ends and electrodes.

    Parameters
    ----------
    name : str
        Preset name or a user's label.
    radius_m : float
        Radius of the cylinder and of the hemispherical ends (m).
    length_m : float
        Tip-to-tip length, hemispheres included (m).
    electrodes : tuple of Electrode
        Ordered head (+x) to tail (-x): electrode 1 first.
    emitter : int
        1-based number of the emitting electrode (default: the last one).
    """

    name: str
    radius_m: float
    length_m: float
    electrodes: tuple[Electrode, ...]
    emitter: int = 0  # 0 means "the last electrode"
    notes: str = ""

    def __post_init__(self):
        if self.emitter == 0:
            object.__setattr__(self, "emitter", int(sum(getattr(e, "sectors", 1) for e in self.electrodes)))
        self.validate()

    # ------------------------------------------------------------------ derived
    @property
    def n_electrodes(self) -> int:
        """Number of electrodes as numbered (every sector counts as one)."""
        return int(sum(e.sectors for e in self.electrodes))

    @property
    def has_sectors(self) -> bool:
        """True when an electrode is split into sectors."""
        return any(e.is_split for e in self.electrodes)

    @property
    def sectors_touch(self) -> bool:
        """True when neighbouring sectors share mesh vertices: a gap of 0, or a split cap (its sectors meet at the tip)."""
        return any(e.is_split and (e.sector_gap_m == 0 or e.kind == "cap") for e in self.electrodes)

    def sector_of(self, number: int) -> tuple[int, int]:
        """(index into ``electrodes`` (0-based), sector (1-based)) of electrode ``number`` (1-based)."""
        k = int(number)
        if not 1 <= k <= self.n_electrodes:
            raise ValueError(f"{self.name or 'sensor'}: {number} is not an electrode number (1..{self.n_electrodes})")
        for index, e in enumerate(self.electrodes):
            if k <= e.sectors:
                return index, k
            k -= e.sectors
        raise AssertionError("unreachable")

    def numbers_of(self, index: int) -> tuple[int, ...]:
        """Electrode numbers (1-based) of the sectors of ``electrodes[index]`` (one number when it is whole)."""
        first = 1 + sum(e.sectors for e in self.electrodes[:index])
        return tuple(range(first, first + self.electrodes[index].sectors))

    def merge_matrix(self) -> np.ndarray:
        """(n_electrodes, len(electrodes)) 0/1 matrix: column j sums the sectors of ``electrodes[j]``.

        ``W.T @ K @ W`` is the conductance matrix of the sectors of each
        electrode driven together (with a gap of 0: the whole electrode's).
        """
        W = np.zeros((self.n_electrodes, len(self.electrodes)))
        for j in range(len(self.electrodes)):
            W[np.asarray(self.numbers_of(j)) - 1, j] = 1.0
        return W

    def merged(self) -> "SensorDescription":
        """The same sensor with every electrode whole (sectors and gaps closed); the emitter's electrode emits."""
        whole = tuple(replace(e, sectors=1, sector_gap_m=0.0) for e in self.electrodes)
        return replace(self, electrodes=whole, emitter=self.sector_of(self.emitter)[0] + 1)

    def with_sectors(self, sectors: dict, gap_m: float = 0.0, emitter: int | None = None) -> "SensorDescription":
        """Split electrodes: ``sectors`` maps electrode numbers of the whole sensor (1-based) to sector counts.

        The emitter keeps its electrode (its first sector when it is split) unless ``emitter`` is given.
        """
        base = self.merged()
        electrodes = list(base.electrodes)
        for number, n in sectors.items():
            if not 1 <= int(number) <= len(electrodes):
                raise ValueError(f"{self.name or 'sensor'}: no electrode {number} to split (1..{len(electrodes)})")
            electrodes[int(number) - 1] = replace(electrodes[int(number) - 1], sectors=int(n),
                                                  sector_gap_m=float(gap_m) if int(n) > 1 else 0.0)
        split = replace(base, electrodes=tuple(electrodes), emitter=1)
        if emitter is None:
            emitter = split.numbers_of(base.emitter - 1)[0]
        return replace(split, emitter=int(emitter))

    def lateral_mirror(self) -> np.ndarray | None:
        """The electrodes' permutation under the sensor's lateral mirror image (y -> -y in its own frame), or None.

        A pose reflected in a vertical plane of the tank (a box's mirror plane, a
        cylinder's diameter) carries the sensor's mirror image: sector ``k`` of
        a ring at azimuth ``phi_k`` (from +y towards +z) lands on azimuth
        ``pi - phi_k``, which is a sector again only when the ring has an even
        number of them. Returns the 0-based indices ``perm`` with ``K`` of the
        reflected pose ``= K[perm][:, perm]`` of the pose (an involution;
        whole electrodes map onto themselves), or None when a split electrode
        has an odd number of sectors (no mirror image of the sensor is the
        sensor).

        Example
        -------
        >>> preset("angels-4").with_sectors({2: 4}).lateral_mirror().tolist()
        [0, 3, 2, 1, 4, 5, 6]
        >>> preset("angels-4").with_sectors({2: 3}).lateral_mirror() is None
        True
        """
        perm = []
        for j, e in enumerate(self.electrodes):
            first = self.numbers_of(j)[0] - 1
            if e.sectors % 2 and e.sectors > 1:
                return None
            n = e.sectors
            perm += [first + (n // 2 - c) % n for c in range(n)]
        return np.array(perm, dtype=np.int64)

    def lateral_weights(self) -> tuple[tuple[int, ...], np.ndarray]:
        """The lateral signal "left minus right" of every split electrode whose sectors are all receivers.

        Returns the indices (0-based, into ``electrodes``) of those electrodes
        and ``W`` (len, n_electrodes): ``W @ I`` is, for each, the sum of its
        sectors' currents weighted by ``cos(phi_k)``, ``phi_k`` the sector's
        centre azimuth from +y (the left side when the head points forward and
        +z is up). For 2 or 4 sectors that is sector 1 minus the opposite one.

        Example
        -------
        >>> s = preset("angels-4").with_sectors({2: 4})
        >>> s.lateral_weights()[1][0].round(6).tolist()
        [0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0]
        """
        rows, split = [], []
        for j, e in enumerate(self.electrodes):
            numbers = self.numbers_of(j)
            if not e.is_split or self.emitter in numbers:
                continue
            w = np.zeros(self.n_electrodes)
            w[np.asarray(numbers) - 1] = np.cos(sector_azimuths_rad(e, self.radius_m)[0])
            w[np.abs(w) < 1e-12] = 0.0
            rows.append(w)
            split.append(j)
        return tuple(split), np.array(rows).reshape(len(rows), self.n_electrodes)

    @property
    def electrode_labels(self) -> tuple[str, ...]:
        """A short name per electrode number: ``"3"`` for a whole electrode, ``"2.1"`` for sector 1 of the second."""
        labels = []
        for index, e in enumerate(self.electrodes, start=1):
            labels += [str(index)] if e.sectors == 1 else [f"{index}.{k}" for k in range(1, e.sectors + 1)]
        return tuple(labels)

    @property
    def receivers(self) -> tuple[int, ...]:
        """1-based numbers of the receiving electrodes, in electrode order."""
        return tuple(k for k in range(1, self.n_electrodes + 1) if k != self.emitter)

    @property
    def electrode_centres_m(self) -> np.ndarray:
        """(n, 3) centres of the electrodes' axial extents, sensor frame (m), on the axis (every sector too)."""
        c = np.zeros((self.n_electrodes, 3))
        c[:, 0] = [self.electrodes[self.sector_of(k)[0]].x_centre_m for k in range(1, self.n_electrodes + 1)]
        return c

    def with_emitter(self, emitter: int) -> "SensorDescription":
        return replace(self, emitter=emitter)

    # --------------------------------------------------------------- validation
    def validate(self) -> None:
        """Raise ``ValueError`` naming the part when the description is impossible."""
        name = self.name or "sensor"
        if not (self.radius_m > 0 and np.isfinite(self.radius_m)):
            raise ValueError(f"{name}: radius_m must be positive, got {self.radius_m}")
        if not self.length_m > 2 * self.radius_m:
            raise ValueError(f"{name}: length_m ({self.length_m}) must exceed the diameter ({2 * self.radius_m})")
        n = len(self.electrodes)
        if n < 1 or (n < 2 and not any(getattr(e, "sectors", 1) > 1 for e in self.electrodes)):
            raise ValueError(f"{name}: a sensor needs at least 2 electrodes, got {n}")
        half = 0.5 * self.length_m
        for k, e in enumerate(self.electrodes, start=1):
            self._validate_sectors(k, e)
            if e.kind not in ("cap", "ring"):
                raise ValueError(f"{name}: electrode {k} has unknown kind {e.kind!r} (cap or ring)")
            if not e.x_min_m < e.x_max_m:
                raise ValueError(f"{name}: electrode {k} has x_min_m >= x_max_m ({e.x_min_m} >= {e.x_max_m})")
            if e.x_min_m < -half - 1e-12 or e.x_max_m > half + 1e-12:
                raise ValueError(f"{name}: electrode {k} extends beyond the sensor tips (+-{half} m)")
            if e.kind == "cap":
                at_head = abs(e.x_max_m - half) < 1e-12
                at_tail = abs(e.x_min_m + half) < 1e-12
                if not (at_head or at_tail):
                    raise ValueError(f"{name}: electrode {k} is a cap but does not reach a tip")
            else:
                if e.x_min_m < -half + self.radius_m - 1e-12 or e.x_max_m > half - self.radius_m + 1e-12:
                    raise ValueError(f"{name}: ring electrode {k} reaches onto a hemispherical end")
        # geometric order head -> tail, no overlap or touching
        for k in range(1, n):
            a, b = self.electrodes[k - 1], self.electrodes[k]
            if not b.x_max_m < a.x_min_m:
                raise ValueError(
                    f"{name}: electrodes {k} and {k + 1} touch or overlap, or are not ordered head (+x) to tail (-x)"
                )
        if not 1 <= self.emitter <= self.n_electrodes:
            raise ValueError(f"{name}: emitter {self.emitter} is not an electrode number (1..{self.n_electrodes})")

    def _validate_sectors(self, k: int, e: Electrode) -> None:
        name = self.name or "sensor"
        sectors, gap = e.sectors, e.sector_gap_m
        if isinstance(sectors, bool) or not isinstance(sectors, (int, np.integer)) or not 1 <= sectors <= MAX_SECTORS:
            raise ValueError(f"{name}: electrode {k} has sectors {sectors!r}; give a whole number 1..{MAX_SECTORS}")
        if isinstance(gap, bool) or not isinstance(gap, (int, float, np.floating)) or not np.isfinite(gap) or gap < 0:
            raise ValueError(f"{name}: electrode {k} has sector_gap_m {gap!r}; give a length >= 0 (m)")
        if sectors == 1 and gap != 0:
            raise ValueError(f"{name}: electrode {k} has a sector_gap_m but is not split (sectors 1)")
        if sectors > 1 and sectors * gap >= 2 * np.pi * self.radius_m:
            raise ValueError(f"{name}: electrode {k}: {sectors} gaps of {gap} m leave nothing of the circumference "
                             f"({2 * np.pi * self.radius_m:.6g} m) to the sectors")

    # -------------------------------------------------------------------- files
    def to_dict(self) -> dict:
        """Plain data (a whole electrode is written without its ``sectors`` and ``sector_gap_m``)."""
        d = asdict(self)
        d["electrodes"] = [{k: v for k, v in asdict(e).items() if e.is_split or k not in ("sectors", "sector_gap_m")}
                           for e in self.electrodes]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SensorDescription":
        try:
            electrodes = tuple(_electrode_from_dict(e) for e in d["electrodes"])
            return cls(
                name=d.get("name", ""),
                radius_m=float(d["radius_m"]),
                length_m=float(d["length_m"]),
                electrodes=electrodes,
                emitter=int(d.get("emitter", 0)),
                notes=d.get("notes", ""),
            )
        except KeyError as exc:
            raise ValueError(f"sensor description lacks the key {exc}") from None
        except TypeError as exc:
            raise ValueError(f"sensor description has a malformed electrode: {exc}") from None


MAX_SECTORS = 64
"""Most sectors one electrode may be split into."""


def _electrode_from_dict(e) -> Electrode:
    if not isinstance(e, dict):
        raise TypeError(f"an electrode is a table of keys, got {type(e).__name__}")
    e = dict(e)
    if "sectors" in e:
        n = e["sectors"]
        if isinstance(n, float) and n.is_integer():
            n = int(n)
        e["sectors"] = n
    if "sector_gap_m" in e and isinstance(e["sector_gap_m"], int) and not isinstance(e["sector_gap_m"], bool):
        e["sector_gap_m"] = float(e["sector_gap_m"])
    return Electrode(**e)


def _angels(n: int) -> SensorDescription:
    """Preset geometry of the paper's sensors (see ``PRESETS`` for the choices)."""
    length, radius = _ANGELS_DIMENSIONS["length_m"], _ANGELS_DIMENSIONS["radius_m"]
    half = 0.5 * length
    cap = _ANGELS_DIMENSIONS.get(f"cap_extent_{n}_m", _ANGELS_DIMENSIONS["cap_extent_m"])
    electrodes = [Electrode("cap", half - cap, half)]
    if n == 4:
        w, xc = _ANGELS_DIMENSIONS["ring_width_m"], _ANGELS_DIMENSIONS["ring_centre_m"]
        electrodes += [Electrode("ring", xc - w / 2, xc + w / 2), Electrode("ring", -xc - w / 2, -xc + w / 2)]
    electrodes.append(Electrode("cap", -half, -half + cap))
    return SensorDescription(
        name=f"angels-{n}", radius_m=radius, length_m=length, electrodes=tuple(electrodes), notes=_ANGELS_NOTES
    )


# The paper gives the 20 cm length only. The other dimensions were fitted with
# our mesh-converged BEM (validation/studies/bem_paper.py --fit: ring elements
# on the meridian, which the surface BEM with its edge correction reproduces):
# the radius, cap extent, ring width and ring centre of angels-4 by least
# squares on the paper's free-space S_BEM table (mean relative error 0.07 %,
# every entry within 0.22 %; the table leaves a shallow valley of radius
# against electrode extents, see fit_angels4); angels-2 keeps the same body and
# its cap extent is set so that its free-space conductance gives the paper's
# PSM equivalent radius a = 0.71 cm at L = 20 cm (S = 4 pi sigma / (2/a - 2/L)).
_ANGELS_DIMENSIONS = {
    "length_m": 0.20,
    "radius_m": 0.012184,
    "cap_extent_m": 0.008304,  # end electrodes of angels-4: a spherical cap shorter than the hemisphere
    "cap_extent_2_m": 0.008088,  # end electrodes of angels-2
    "ring_width_m": 0.006541,
    "ring_centre_m": 0.031430,
}
_ANGELS_NOTES = (
    "Paper sensor (Jawad et al.): 20 cm long; diameter, cap and ring extents are not given in the paper "
    "and were chosen so that the free-space BEM matches the paper's S_BEM table."
)

PRESETS = {"angels-2": lambda: _angels(2), "angels-4": lambda: _angels(4)}


def preset(name: str) -> SensorDescription:
    """Return a preset sensor by name (``angels-2``, ``angels-4``)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown sensor preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None


MAX_SENSOR_FILE_BYTES = 1 << 20
"""Largest sensor file read (bytes): a description is a few hundred bytes."""


def _read_regular_file(path: Path, what: str) -> str:
    """Text of ``path`` if it is a regular file of reasonable size, else ``ValueError``.

    The file is opened without blocking and checked on the open descriptor, so
    a directory, a FIFO or a device (``/dev/zero``) is refused rather than read
    (which would raise a traceback, hang, or never end).
    """
    import os
    import stat

    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except IsADirectoryError:
        raise ValueError(f"{what} {str(path)!r} is a directory, not a sensor file") from None
    except OSError as exc:
        raise ValueError(f"{what} {str(path)!r} cannot be opened: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise ValueError(f"{what} {str(path)!r} is a directory, not a sensor file")
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(
                f"{what} {str(path)!r} is not a regular file (a device, FIFO or socket); give a .json or .toml file"
            )
        if st.st_size > MAX_SENSOR_FILE_BYTES:
            raise ValueError(
                f"{what} {str(path)!r} is {st.st_size} bytes; a sensor description is a small text file "
                f"(at most {MAX_SENSOR_FILE_BYTES} bytes read)"
            )
        raw = os.read(fd, MAX_SENSOR_FILE_BYTES + 1)
    finally:
        os.close(fd)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{what} {str(path)!r} is not UTF-8 text: {exc}") from None


def load_sensor(spec: str | Path, relative_to: str | Path | None = None) -> SensorDescription:
    """A preset name, or a path to a sensor file (``.json`` or ``.toml``).

    A path is data: it must name a regular file (not a directory, FIFO or
    device); anything else is refused with a ``ValueError`` naming the path.

    Parameters
    ----------
    spec : str or Path
        Preset name (see ``PRESETS``) or a file path.
    relative_to : str or Path, optional
        Folder a relative path is taken from (the folder of the log or scene
        file that names it). The path must then stay inside that folder: an
        absolute path, or one that climbs out with ``..`` or a link, is
        refused (a path in a user's file is data, never a way out).

    Examples
    --------
    >>> load_sensor("angels-4").n_electrodes
    4
    >>> try:
    ...     load_sensor(".")
    ... except ValueError as exc:
    ...     print("directory" in str(exc))
    True
    """
    spec_str = str(spec)
    if spec_str in PRESETS:
        return preset(spec_str)
    path = Path(spec_str)
    if relative_to is not None:
        folder = Path(relative_to)
        if path.is_absolute() or not (folder / path).resolve().is_relative_to(folder.resolve()):
            raise ValueError(
                f"sensor {spec_str!r} leads outside the folder of the file that names it ({folder}): a sensor file "
                "named in a log or scene file must lie in that folder or below it (give a relative path without "
                "'..', or a preset name)"
            )
        path = folder / path
    if not path.exists():
        raise ValueError(f"sensor {spec_str!r} is neither a preset ({', '.join(sorted(PRESETS))}) nor an existing file")
    text = _read_regular_file(path, "sensor")
    if path.suffix == ".toml":
        import tomllib

        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: not valid TOML: {exc}") from None
        data = data.get("sensor", data)
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a sensor file holds one object (a table of keys), got {type(data).__name__}")
    try:
        return SensorDescription.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except (TypeError, KeyError) as exc:
        raise ValueError(f"{path}: not a sensor description: {exc}") from None


def save_sensor(sensor: SensorDescription, path: str | Path) -> None:
    """Write a sensor description as JSON."""
    Path(path).write_text(json.dumps(sensor.to_dict(), indent=2) + "\n")
