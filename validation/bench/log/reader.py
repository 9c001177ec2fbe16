"""Strict reader of bench logs (format version 1, specified in ``docs/bench-log.md``).

A bench log is refused, with the file, the line and the reason, when the
first line or the version is wrong, the file starts with a byte-order mark,
a line ends otherwise than with ``\\n``, the meta JSON is bad, repeats a key
or lacks a required key, a required column is missing, a value is not a
finite number written plainly (padding, ``1_0``, hex and overflow are
refused: the reader never changes a number), time goes backwards, or the
receiver columns do not match the sensor. A final line cut
short by a crash (no line end) is reported in ``BenchLog.warnings`` and
skipped, never taken. Nothing is guessed.

Example
-------
>>> from electrosense.validation.bench.log import read_bench_log
>>> log = read_bench_log("run.csv")                          # doctest: +SKIP
>>> log.poses.shape, log.currents_A.shape, log.warnings      # doctest: +SKIP
((161, 4), (161, 3), [])
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.log.header import (
    BASE_COLUMNS,
    META_LINE,
    OPTIONAL_NUMERIC_COLUMNS,
    PASS_COLUMN,
    Header,
    check_columns,
    interpret_meta,
    parse_format_line,
    parse_meta_line,
    receiver_columns,
    same_run,
)

__all__ = ["BenchLog", "read_bench_log", "read_bench_logs", "read_header"]

_NON_FINITE = {"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"}
_DECIMAL = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
"""A number as the spec writes it: decimal digits, an optional point and exponent; nothing else."""
MAX_PASS = 2**53
"""Largest pass number taken (every integer up to it is exact as a double)."""
BOM = "\ufeff"


@dataclass
class BenchLog:
    """A bench log in memory: metadata, the table, and the physics it implies.

    Attributes
    ----------
    meta : dict
        The meta line's JSON object, unknown keys included.
    data : pandas.DataFrame
        One row per sample, the file's columns in the file's order (extra
        columns kept; numeric where every value is a number).
    sensor : SensorDescription
        The sensor of the meta line, with its emitter.
    tank : Tank or None
        The tank (``None``: unbounded water).
    sigma_S_per_m : float
        Nominal conductivity from the meta line.
    emitter : int
        1-based emitter.
    warnings : list of str
        What was reported and skipped (a final line cut short).
    path : Path
        The file (the first one for logs read with :func:`read_bench_logs`).
    paths : tuple of Path
        Every file the log was read from.
    """

    meta: dict
    data: pd.DataFrame
    sensor: SensorDescription
    tank: Tank | None
    sigma_S_per_m: float
    emitter: int
    warnings: list[str] = field(default_factory=list)
    path: Path | None = None
    paths: tuple[Path, ...] = ()

    # ---------------------------------------------------------------- columns
    @property
    def receivers(self) -> tuple[int, ...]:
        """1-based receiver numbers in electrode order."""
        return self.sensor.receivers

    @property
    def current_columns(self) -> tuple[str, ...]:
        return receiver_columns(self.sensor)

    @property
    def n_samples(self) -> int:
        return len(self.data)

    def __len__(self) -> int:
        return len(self.data)

    # ----------------------------------------------------------------- arrays
    @property
    def t_s(self) -> np.ndarray:
        """(P,) seconds since the start."""
        return self.data["t_s"].to_numpy(dtype=float)

    @property
    def poses(self) -> np.ndarray:
        """(P, 4) poses (x_m, y_m, z_m, yaw_rad) in the tank frame."""
        return self.data[["x_m", "y_m", "z_m", "yaw_rad"]].to_numpy(dtype=float)

    @property
    def U_V(self) -> np.ndarray:
        """(P,) emitter voltage relative to the receivers."""
        return self.data["U_V"].to_numpy(dtype=float)

    @property
    def currents_A(self) -> np.ndarray:
        """(P, n-1) receiver currents, positive from the water into the receiver."""
        return self.data[list(self.current_columns)].to_numpy(dtype=float)

    @property
    def resistance_ohm(self) -> np.ndarray:
        """(P, n-1) U / I of each receiver."""
        return self.U_V[:, None] / self.currents_A

    @property
    def passes(self) -> np.ndarray:
        """(P,) pass number of each sample: the ``pass`` column, or 0 when the file has none."""
        if PASS_COLUMN in self.data:
            return self.data[PASS_COLUMN].to_numpy(dtype=np.int64)
        return np.zeros(len(self.data), dtype=np.int64)

    @property
    def pass_numbers(self) -> np.ndarray:
        """The distinct pass numbers, in the order they appear."""
        p = self.passes
        _, first = np.unique(p, return_index=True)
        return p[np.sort(first)]

    def select_pass(self, number: int) -> "BenchLog":
        """The samples of one pass, as a log of its own."""
        keep = self.passes == number
        if not keep.any():
            raise ValueError(f"no pass {number} in {self.path}; passes: {self.pass_numbers.tolist()}")
        return BenchLog(self.meta, self.data[keep].reset_index(drop=True), self.sensor, self.tank,
                        self.sigma_S_per_m, self.emitter, list(self.warnings), self.path, self.paths)


# --------------------------------------------------------------------- reading
def _decode(raw: bytes, file, first_line: bool = True) -> str:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise BenchLogError(file, line, f"not UTF-8 text (byte 0x{raw[exc.start]:02x})") from None
    if first_line and text.startswith(BOM):
        raise BenchLogError(
            file, 1, "the file starts with a UTF-8 byte-order mark (BOM, bytes EF BB BF); a bench log is UTF-8 "
            "without a BOM: save it again without one (e.g. 'UTF-8' rather than 'UTF-8 with BOM')"
        )
    return text


def _check_line_end(line: str, number: int, file) -> None:
    """Refuse a carriage return in a line: Windows (\\r\\n) or old Mac (\\r only) line ends."""
    if "\r" not in line:
        return
    if line.endswith("\r") and "\r" not in line[:-1]:
        raise BenchLogError(file, number, "line ends must be \\n; this line ends with \\r\\n (Windows line ends)")
    raise BenchLogError(
        file, number, "line ends must be \\n; this line holds a carriage return (\\r) inside it: the file has "
        "CR-only (old Mac) line ends, or a stray \\r"
    )


def _split_lines(text: str, file) -> tuple[list[str], str | None]:
    """Complete lines, and the final fragment without a line end (or None)."""
    lines = text.split("\n")
    tail = lines.pop()  # "" when the file ends with a line end
    for i, line in enumerate(lines):
        _check_line_end(line, i + 1, file)
    if tail and not lines and "\r" in tail:
        _check_line_end(tail, 1, file)
    return lines, (tail if tail != "" else None)


def read_header(path: str | Path) -> tuple[Header, list[str], int]:
    """The header of a log: (checked header, columns, line number of the column row).

    Reads only as far as the column row; used to append to an existing log.
    """
    path = Path(path)
    with open(path, "rb") as f:
        head_lines = []
        for raw in f:
            if not raw.endswith(b"\n"):
                if b"\r" in raw:
                    _check_line_end(_decode(raw, path, first_line=not head_lines), len(head_lines) + 1, path)
                break
            text = _decode(raw, path, first_line=not head_lines)
            _check_line_end(text[:-1], len(head_lines) + 1, path)
            head_lines.append(text[:-1])
            if len(head_lines) > 2 and not text.startswith("#"):
                break
    return _parse_header(head_lines, path)


def _parse_header(lines: list[str], file) -> tuple[Header, list[str], int]:
    if not lines:
        raise BenchLogError(file, 1, "the file is empty (or its first line is cut short)")
    parse_format_line(lines[0], file)
    if len(lines) < 2:
        raise BenchLogError(file, META_LINE, "the file ends before the meta line")
    meta = parse_meta_line(lines[1], file)
    header = interpret_meta(meta, file, folder=Path(file).parent)
    i = 2
    while i < len(lines) and lines[i].startswith("#"):
        i += 1
    if i >= len(lines):
        raise BenchLogError(file, i + 1, "the file ends before the column row")
    columns = lines[i].split(",")
    check_columns(columns, header, file, i + 1)
    return header, columns, i + 1


def _first_bad(values: list[str]) -> tuple[int, str] | None:
    """Index and reason of the first value that is not a finite number written plainly, or None.

    A value is taken only when it is a plain decimal number (``1``, ``-0.5``,
    ``1.0314e-03``): no padding, no digit separators (``1_0``), no hex, no
    ``nan``/``inf``, and no overflow (``1e400``).
    """
    match = _DECIMAL.fullmatch
    for i, v in enumerate(values):
        if match(v):
            continue
        if v == "":
            return i, "empty value"
        if v != v.strip():
            return i, f"value {v!r} has spaces around it (values are written without padding)"
        if v.strip().lower() in _NON_FINITE:
            return i, f"non-finite value {v!r}"
        if "_" in v:
            return i, f"value {v!r} holds an underscore (digit separators are not part of the format)"
        return i, f"non-numeric value {v!r}"
    arr = np.array(values, dtype=float)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        return i, f"value {values[i]!r} overflows a double (non-finite)"
    return None


def _column_values(rows: list[list[str]], j: int) -> list[str]:
    return [r[j] for r in rows]


def _extra_column(values: list[str]) -> pd.Series:
    """An extra column: numeric when every value is a number, else kept as text."""
    s = pd.Series(values, dtype=object)
    try:
        return pd.to_numeric(s, errors="raise")
    except (ValueError, TypeError):
        return s


def read_bench_log(path: str | Path) -> BenchLog:
    """Read one bench log, strictly (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.csv`` file. A sensor given as a path in the meta line is read
        relative to the log's folder.

    Returns
    -------
    BenchLog

    Raises
    ------
    BenchLogError
        With ``.file``, ``.line`` and ``.reason``.
    """
    path = Path(path)
    text = _decode(path.read_bytes(), path)
    lines, tail = _split_lines(text, path)
    warnings = []
    if tail is not None:
        n = len(lines) + 1
        warnings.append(f"line {n}: last line cut short, skipped ({tail[:60]!r})")
    header, columns, column_line = _parse_header(lines, path)
    body = lines[column_line:]
    first = column_line + 1  # line number of body[0]
    rows = []
    ncol = len(columns)
    for i, line in enumerate(body):
        fields = line.split(",")
        if len(fields) != ncol:
            if line == "":
                raise BenchLogError(path, first + i, "empty line in the data")
            if line.startswith("#"):
                raise BenchLogError(path, first + i, "comment line after the column row (comments go before it)")
            raise BenchLogError(path, first + i, f"{len(fields)} fields, the column row has {ncol}")
        rows.append(fields)

    numeric = [c for c in columns if c in BASE_COLUMNS or c in OPTIONAL_NUMERIC_COLUMNS
               or c in receiver_columns(header.sensor) or c == PASS_COLUMN]
    problems = []
    for c in numeric:
        bad = _first_bad(_column_values(rows, columns.index(c)))
        if bad is not None:
            problems.append((bad[0], columns.index(c), f"{bad[1]} in column {c}"))
    if problems:
        i, _, reason = min(problems)
        raise BenchLogError(path, first + i, reason)

    data = {}
    for j, c in enumerate(columns):
        values = _column_values(rows, j)
        if c in numeric:
            data[c] = np.array(values, dtype=float)
        else:
            data[c] = _extra_column(values)
    if PASS_COLUMN in data:
        p = data[PASS_COLUMN]
        frac = np.flatnonzero(p != np.round(p))
        if frac.size:
            i = int(frac[0])
            raise BenchLogError(path, first + i, f"pass must be an integer, found {rows[i][columns.index(PASS_COLUMN)]!r}")
        huge = np.flatnonzero(np.abs(p) > MAX_PASS)
        if huge.size:
            i = int(huge[0])
            raise BenchLogError(path, first + i, f"pass {rows[i][columns.index(PASS_COLUMN)]!r} is out of range "
                                                 f"(a pass number is an integer of magnitude at most 2**53)")
        data[PASS_COLUMN] = p.astype(np.int64)
    t = data["t_s"]
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise BenchLogError(path, first + i, f"time goes backwards: t_s = {rows[i][columns.index('t_s')]} after "
                                             f"{rows[i - 1][columns.index('t_s')]}")
    frame = pd.DataFrame(data, columns=columns)
    return BenchLog(meta=header.meta, data=frame, sensor=header.sensor, tank=header.tank,
                    sigma_S_per_m=header.sigma_S_per_m, emitter=header.emitter, warnings=warnings,
                    path=path, paths=(path,))


def read_bench_logs(paths) -> BenchLog:
    """Several files of one run, concatenated into passes.

    The files must agree on the sensor, emitter, tank, water depth and
    nominal conductivity. Their passes are renumbered 0, 1, 2, ... in file
    order (a file without a ``pass`` column is one pass); the table gains the
    columns ``pass`` and ``file`` (the file name). ``t_s`` is kept as in each
    file, so it is non-decreasing within each file.

    Example
    -------
    >>> log = read_bench_logs(["run-1.csv", "run-2.csv"])     # doctest: +SKIP
    >>> log.pass_numbers                                     # doctest: +SKIP
    array([0, 1])
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("read_bench_logs needs at least one file")
    logs = [read_bench_log(p) for p in paths]
    first = logs[0]
    ref = Header(first.meta, first.sensor, first.tank, first.sigma_S_per_m, first.emitter)
    frames, warnings, offset = [], [], 0
    for log in logs:
        differ = same_run(ref, Header(log.meta, log.sensor, log.tank, log.sigma_S_per_m, log.emitter))
        if differ:
            raise BenchLogError(log.path, META_LINE, f"not the same run as {first.path.name}: the meta differs on "
                                                     f"{', '.join(differ)}")
        frame = log.data.copy()
        own = log.passes
        _, rank = np.unique(own, return_inverse=True)
        frame[PASS_COLUMN] = offset + rank.astype(np.int64)
        offset += int(rank.max()) + 1 if len(rank) else 0
        frame["file"] = log.path.name
        frames.append(frame)
        warnings += [f"{log.path.name}, {w}" for w in log.warnings]
    data = pd.concat(frames, ignore_index=True)
    return BenchLog(meta=first.meta, data=data, sensor=first.sensor, tank=first.tank,
                    sigma_S_per_m=first.sigma_S_per_m, emitter=first.emitter, warnings=warnings,
                    path=first.path, paths=tuple(paths))
