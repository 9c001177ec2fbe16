"""Writing bench logs: whole tables at once, or record by record as they arrive.

:class:`BenchLogWriter` is what an acquisition uses: the file is append-only,
every record goes to the operating system in one ``write`` as soon as it is
given (flushed), and the data are synced to the disk (``fsync``) at most
``sync_interval_s`` after they were written, so that a ``kill -9`` or a power
cut loses at most that last fraction of a second and leaves at most one
partial last line, which the reader reports and skips. It refuses to touch an
existing file unless told to append.

Every value is checked before it is written: the writer never produces a
file that :func:`~validation.bench.log.read_bench_log` would refuse.

Example
-------
>>> from electrosense.validation.bench.log import BenchLogWriter
>>> meta = {"sensor": "angels-2", "emitter": 2, "tank_m": [1, 1, 1], "sigma_S_per_m": 0.0354}
>>> with BenchLogWriter("run.csv", meta) as w:                      # doctest: +SKIP
...     w.write([0.0, -0.38, 0.0, 0.0, 0.0, 1.0, 1.6e-3])
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.log.header import (
    BASE_COLUMNS,
    FORMAT_LINE,
    OPTIONAL_NUMERIC_COLUMNS,
    PASS_COLUMN,
    check_columns,
    format_meta_line,
    interpret_meta,
    receiver_columns,
    standard_columns,
)

__all__ = ["BenchLogWriter", "write_bench_log", "bench_log_table", "format_value"]

_FORBIDDEN = (",", "\n", "\r")


def format_value(value, numeric: bool, column: str = "") -> str:
    """One CSV field.

    Numbers are written with the shortest text that reads back to the same
    float (``repr``); integers as integers. Text given for a numeric column
    (e.g. a device's own formatting) is kept verbatim once checked to be a
    finite number. Raises ``ValueError`` for what the reader would refuse.
    """
    where = f" in column {column}" if column else ""
    if isinstance(value, str):
        if any(ch in value for ch in _FORBIDDEN):
            raise ValueError(f"value {value!r}{where} contains a comma or a line break")
        if numeric:
            try:
                x = float(value)
            except ValueError:
                raise ValueError(f"non-numeric value {value!r}{where}") from None
            if not math.isfinite(x) or value != value.strip() or "_" in value:
                raise ValueError(f"value {value!r}{where} is not a plain finite number")
        return value
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"boolean value {value!r}{where}: write a number")
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        x = float(value)
        if not math.isfinite(x):
            raise ValueError(f"non-finite value {x!r}{where}")
        return repr(x)
    if numeric:
        raise ValueError(f"value {value!r}{where} is not a number")
    return format_value(str(value), False, column)


def _numeric_columns(columns, sensor) -> set[str]:
    return set(BASE_COLUMNS) | set(OPTIONAL_NUMERIC_COLUMNS) | set(receiver_columns(sensor)) | {PASS_COLUMN}


def _header_text(meta: dict, columns: Sequence[str], comments: Sequence[str]) -> str:
    lines = [FORMAT_LINE, format_meta_line(meta)]
    for c in comments:
        if "\n" in c or "\r" in c:
            raise ValueError(f"a comment must be one line: {c!r}")
        lines.append("# " + c)
    lines.append(",".join(columns))
    return "\n".join(lines) + "\n"


def _fsync_folder(path: Path) -> None:
    """Make a new file's directory entry durable too (POSIX; a no-op elsewhere)."""
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class BenchLogWriter:
    """Append-only, crash-safe writer of one bench log.

    Parameters
    ----------
    path : str or Path
        The log. Refused if it exists, unless ``append=True``.
    meta : dict
        The meta object (required keys: sensor, emitter, tank_m, sigma_S_per_m).
    columns : sequence of str, optional
        Column row; default: the spec's columns for the sensor
        (t_s, pose, U_V, receiver currents).
    append : bool
        Go on writing an existing log of the same run (same sensor, emitter,
        tank and conductivity, same columns). A final line cut short by an
        earlier crash is removed from the file first and kept in
        ``recovered_tail`` so that the caller can keep it elsewhere.
    sync_interval_s : float
        Longest time a written record may stay unsynced to the disk.
    comments : sequence of str
        ``#`` lines written after the meta line (new files only).

    Attributes
    ----------
    n_written : int
        Records written by this writer.
    last_t_s : float or None
        ``t_s`` of the last record in the file.
    recovered_tail : str or None
        A cut-short last line removed when appending.
    last_row : dict or None
        When appending: the file's last record, column name to text as written.
    """

    def __init__(self, path, meta: dict, columns: Sequence[str] | None = None, append: bool = False,
                 sync_interval_s: float = 0.5, comments: Sequence[str] = ()):
        self.path = Path(path)
        self.sync_interval_s = float(sync_interval_s)
        header = interpret_meta(meta, self.path, folder=self.path.parent)
        self.header = header
        self.recovered_tail: str | None = None
        self.last_t_s: float | None = None
        self.last_row: dict[str, str] | None = None
        self.n_written = 0
        self._unsynced_since: float | None = None
        exists = self.path.exists()
        if exists and not append:
            raise FileExistsError(f"{self.path} exists; refusing to overwrite a bench log (append to it instead)")
        if exists:
            columns = self._open_for_append(meta, columns)
        else:
            columns = tuple(columns) if columns is not None else standard_columns(header.sensor)
            check_columns(list(columns), header, self.path, 3 + len(comments))
            text = _header_text(meta, columns, comments)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
            os.write(self._fd, text.encode("utf-8"))
            os.fsync(self._fd)
            _fsync_folder(self.path)
        self.columns = tuple(columns)
        self._numeric = _numeric_columns(self.columns, header.sensor)
        self._t_index = self.columns.index("t_s")

    def _open_for_append(self, meta, columns):
        from electrosense.validation.bench.log.header import same_run
        from electrosense.validation.bench.log.reader import read_header

        old, old_columns, _ = read_header(self.path)
        differ = same_run(old, self.header)
        if differ:
            raise BenchLogError(self.path, 2, f"cannot append: the existing log is of another run "
                                              f"(meta differs on {', '.join(differ)})")
        if columns is not None and tuple(columns) != tuple(old_columns):
            raise BenchLogError(self.path, None, f"cannot append: the existing log has the columns "
                                                 f"{','.join(old_columns)}, not {','.join(columns)}")
        self._fd = os.open(self.path, os.O_RDWR | os.O_APPEND)
        size = os.fstat(self._fd).st_size
        start = max(0, size - (1 << 20))  # records are short: the last MiB holds the last lines
        block = os.pread(self._fd, size - start, start)
        if block and not block.endswith(b"\n"):
            # a record cut short by a crash: keep it aside, then cut it off the file
            cut = block.rfind(b"\n") + 1
            self.recovered_tail = block[cut:].decode("utf-8", "backslashreplace")
            os.ftruncate(self._fd, start + cut)
            os.fsync(self._fd)
            block = block[:cut]
        last = block.rstrip(b"\n").rsplit(b"\n", 1)[-1].decode("utf-8", "replace")
        fields = last.split(",")
        if len(fields) == len(old_columns) and last != ",".join(old_columns):
            self.last_t_s = float(fields[old_columns.index("t_s")])
            self.last_row = dict(zip(old_columns, fields))
        return tuple(old_columns)

    # --------------------------------------------------------------- records
    def format_row(self, row) -> str:
        """The CSV line (with its line end) for one record; raises ``ValueError`` if the reader would refuse it."""
        if isinstance(row, Mapping):
            missing = [c for c in self.columns if c not in row]
            if missing:
                raise ValueError(f"record lacks the column{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
            unknown = [str(c) for c in row if c not in self.columns]
            if unknown:
                raise ValueError(f"record has values for columns the log does not have: {', '.join(unknown)}")
            row = [row[c] for c in self.columns]
        row = list(row)
        if len(row) != len(self.columns):
            raise ValueError(f"record has {len(row)} values, the log has {len(self.columns)} columns")
        fields = [format_value(v, c in self._numeric, c) for v, c in zip(row, self.columns)]
        if PASS_COLUMN in self.columns:
            p = float(fields[self.columns.index(PASS_COLUMN)])
            if p != round(p):
                raise ValueError(f"pass must be an integer, got {p}")
        t = float(fields[self._t_index])
        if self.last_t_s is not None and t < self.last_t_s:
            raise ValueError(f"time goes backwards: t_s = {t} after {self.last_t_s}")
        return ",".join(fields) + "\n"

    def write(self, row) -> None:
        """Append one record (values in column order, or a mapping column -> value) in one write."""
        line = self.format_row(row)
        os.write(self._fd, line.encode("utf-8"))
        self.last_t_s = float(line.split(",")[self._t_index])
        self.n_written += 1
        now = time.monotonic()
        if self._unsynced_since is None:
            self._unsynced_since = now
        self.sync_if_due(now)

    def sync_if_due(self, now: float | None = None) -> bool:
        """fsync if a record has waited ``sync_interval_s``; call it often (the logger does, every 0.1 s)."""
        if self._unsynced_since is None:
            return False
        now = time.monotonic() if now is None else now
        if now - self._unsynced_since >= self.sync_interval_s:
            self.sync()
            return True
        return False

    def sync(self) -> None:
        """fsync now."""
        os.fsync(self._fd)
        self._unsynced_since = None

    def close(self) -> None:
        if getattr(self, "_fd", None) is not None:
            self.sync()
            os.close(self._fd)
            self._fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def write_bench_log(path, meta: dict, data, overwrite: bool = False, comments: Sequence[str] = ()) -> Path:
    """Write a whole bench log at once (atomically: a temporary file renamed into place).

    Parameters
    ----------
    path : str or Path
    meta : dict
        Meta object (required keys: sensor, emitter, tank_m, sigma_S_per_m).
    data : pandas.DataFrame or mapping column -> 1-D array
        The table, columns in the order to write them; must hold the spec's
        columns for the sensor; extra columns are written as they are.
    overwrite : bool
        Replace an existing file (refused otherwise).
    comments : sequence of str
        ``#`` lines after the meta line.

    Example
    -------
    >>> import pandas as pd
    >>> meta = {"sensor": "angels-2", "emitter": 2, "tank_m": None, "sigma_S_per_m": 0.0354}
    >>> df = pd.DataFrame({"t_s": [0.0], "x_m": [0.0], "y_m": [0.0], "z_m": [0.0],
    ...                    "yaw_rad": [0.0], "U_V": [1.0], "I1_A": [1.6e-3]})
    >>> write_bench_log("run.csv", meta, df)                            # doctest: +SKIP
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    frame = data if isinstance(data, pd.DataFrame) else pd.DataFrame(dict(data))
    columns = [str(c) for c in frame.columns]
    header = interpret_meta(meta, path, folder=path.parent)
    check_columns(columns, header, path, 3 + len(comments))
    numeric = _numeric_columns(columns, header.sensor)
    for c in columns:
        if c in numeric and frame[c].dtype.kind in "fiu":
            values = frame[c].to_numpy(dtype=float)
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise ValueError(f"column {c}, row {int(bad[0])}: non-finite value {values[bad[0]]}")
    t = pd.to_numeric(frame["t_s"]).to_numpy(dtype=float)
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"row {i}: time goes backwards (t_s = {t[i]} after {t[i - 1]})")
    pieces = [_header_text(meta, columns, comments)]
    cols = [frame[c].tolist() for c in columns]
    is_num = [c in numeric for c in columns]
    for values in zip(*cols):
        pieces.append(",".join(format_value(v, n, c) for v, n, c in zip(values, is_num, columns)) + "\n")
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write("".join(pieces))
            f.flush()
            os.fsync(f.fileno())
        if not overwrite and path.exists():
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    _fsync_folder(path)
    return path


def sensor_for_log(sensor, log_path, given: str | None = None, overwrite: bool = False, write: bool = True) -> str:
    """What the meta of the bench log ``log_path`` calls ``sensor``: a preset name, the sensor file ``given``
    where it lies in the log's folder or below it (as a relative path: a path in a log is data, never a way out
    of its folder), or else a sensor file written beside the log, ``<stem>.sensor.json``.

    An existing ``<stem>.sensor.json`` of another sensor is refused (``FileExistsError``) unless ``overwrite``;
    ``write=False`` checks and names it without writing (before a long computation whose log will name it).

    Example
    -------
    >>> import dataclasses
    >>> from electrosense.meshes.sensor import preset
    >>> sensor_for_log(preset("angels-4").with_emitter(1), "run.csv")      # a preset: the meta names the emitter
    'angels-4'
    >>> sensor_for_log(dataclasses.replace(preset("angels-4"), name="my-probe"), "run.csv", write=False)
    'run.sensor.json'
    """
    from electrosense.meshes.sensor import PRESETS, load_sensor, preset, save_sensor

    log_path = Path(log_path)
    if (sensor.name in PRESETS and preset(sensor.name).n_electrodes == sensor.n_electrodes
            and preset(sensor.name).with_emitter(sensor.emitter) == sensor):
        return sensor.name
    folder = log_path.parent.resolve()
    if given is not None and str(given) not in PRESETS and Path(given).is_file():
        file = Path(given).resolve()
        if file.is_relative_to(folder) and load_sensor(file) == sensor:
            return file.relative_to(folder).as_posix()
    side = log_path.with_name(log_path.stem + ".sensor.json")
    if side.exists() and not overwrite:
        try:
            same = load_sensor(side) == sensor
        except ValueError:
            same = False
        if not same:
            raise FileExistsError(f"{side} exists and describes another sensor; the log {log_path.name} would name "
                                  "it: move it, choose another output file, or pass overwrite")
    if write:
        save_sensor(sensor, side)
    return side.name


def bench_log_table(poses, U_V, currents_A, receivers, t_s=None, passes=None, temp_C=None) -> dict:
    """The columns of a bench log (format version 1) from arrays, in the spec's order.

    Parameters
    ----------
    poses : (P, 4) array
        ``x_m, y_m, z_m, yaw_rad`` of every sample.
    U_V : float or (P,) array
        Emitter voltage.
    currents_A : (P, n-1) array
        Receiver currents, positive into the receivers, in the order of ``receivers``.
    receivers : sequence of int
        The receivers' electrode numbers (``I<k>_A`` columns).
    t_s : (P,) array, optional
        Sample times; default the sample index (a model run has no clock).
    passes, temp_C : (P,) arrays, optional
        The optional ``pass`` and ``temp_C`` columns.

    Returns
    -------
    dict
        Column name -> (P,) array, for :func:`write_bench_log`.

    Example
    -------
    >>> import numpy as np
    >>> table = bench_log_table(np.zeros((2, 4)), 1.0, np.array([[1e-3, 2e-3], [1e-3, 2e-3]]), [1, 2])
    >>> list(table)
    ['t_s', 'x_m', 'y_m', 'z_m', 'yaw_rad', 'U_V', 'I1_A', 'I2_A']
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 4)
    currents_A = np.asarray(currents_A, dtype=float).reshape(len(poses), -1)
    P = len(poses)
    table = {"t_s": np.arange(P, dtype=float) if t_s is None else np.asarray(t_s, dtype=float),
             "x_m": poses[:, 0], "y_m": poses[:, 1], "z_m": poses[:, 2], "yaw_rad": poses[:, 3],
             "U_V": np.broadcast_to(np.asarray(U_V, dtype=float), (P,))}
    table.update({f"I{k}_A": currents_A[:, j] for j, k in enumerate(receivers)})
    if temp_C is not None:
        table["temp_C"] = np.asarray(temp_C, dtype=float)
    if passes is not None:
        table["pass"] = np.asarray(passes)
    return table
