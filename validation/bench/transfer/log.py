"""The transfer-measurement log: one row per (set-up, drive pair, measurement pair); see docs/transfer-log.md.

::

    # esense-transfer-log 1
    # meta: {"scene": "pail.toml", "source": "phantom.mat"}
    setup,drive_plus,drive_minus,meas_plus,meas_minus,V_V,I_A
    Ref,1,2,4,3,0.9388,0.0046169

``I_A`` (> 0) is driven from ``drive_plus`` into the water and out through
``drive_minus``; ``V_V`` is the voltage of ``meas_plus`` minus ``meas_minus``.
A row whose measurement pair IS the drive pair is the drive pair's own
voltage. The transfer impedance is ``V_V / I_A`` (ohm).

Example
-------
>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
>>> rows = [("Ref", 1, 2, 4, 3, 0.5, 0.001), ("Ref", 1, 2, 1, 2, 3.0, 0.001)]
>>> _ = write_transfer_log(p, {"scene": "pail.toml"}, rows)
>>> log = read_transfer_log(p)
>>> log.setups, log.Z_ohm.tolist()
(('Ref',), [500.0, 3000.0])
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.validation.bench.log.errors import BenchLogError

__all__ = ["TransferLog", "read_transfer_log", "write_transfer_log", "is_transfer_log", "MAGIC", "COLUMNS"]

MAGIC = "# esense-transfer-log 1"
COLUMNS = ("setup", "drive_plus", "drive_minus", "meas_plus", "meas_minus", "V_V", "I_A")
REQUIRED_META = ("scene",)


@dataclass
class TransferLog:
    """A read transfer log: ``meta`` (dict) and one array per column (rows in file order)."""

    path: str
    meta: dict
    setup: np.ndarray
    drive: np.ndarray          # (R, 2) int, 1-based
    measure: np.ndarray        # (R, 2) int, 1-based
    V_V: np.ndarray
    I_A: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def Z_ohm(self) -> np.ndarray:
        """Transfer impedance ``V / I`` of every row (ohm)."""
        return self.V_V / self.I_A

    @property
    def setups(self) -> tuple[str, ...]:
        """Set-up names in order of first appearance."""
        return tuple(dict.fromkeys(self.setup.tolist()))

    @property
    def is_drive_row(self) -> np.ndarray:
        """True on rows that are the drive pair's own voltage."""
        return np.all(self.drive == self.measure, axis=1)

    def scene_path(self) -> Path:
        """The scene file, relative to the log's folder (refused if it leaves that folder)."""
        base = Path(self.path).resolve().parent
        p = (base / str(self.meta["scene"])).resolve()
        if base not in p.parents and p != base:
            raise BenchLogError(self.path, 2, f"scene {self.meta['scene']!r} lies outside the log's folder")
        return p

    def select(self, setup: str) -> "TransferLog":
        m = self.setup == setup
        return TransferLog(self.path, self.meta, self.setup[m], self.drive[m], self.measure[m], self.V_V[m],
                           self.I_A[m], {k: v[m] for k, v in self.extra.items()})


def is_transfer_log(path) -> bool:
    """True if the file's first line is the transfer log's."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\r\n") == MAGIC
    except (OSError, UnicodeDecodeError):
        return False


def write_transfer_log(path, meta: dict, rows) -> Path:
    """Write rows ``(setup, drive_plus, drive_minus, meas_plus, meas_minus, V_V, I_A)``; returns the path."""
    for key in REQUIRED_META:
        if key not in meta:
            raise ValueError(f"transfer log meta needs the key {key!r}")
    path = Path(path)
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(MAGIC + "\n# meta: " + json.dumps(meta) + "\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(COLUMNS)
        for r in rows:
            s, a, b, p, q, v, i = r
            w.writerow([s, int(a), int(b), int(p), int(q), repr(float(v)), repr(float(i))])
    return path


def read_transfer_log(path) -> TransferLog:
    """Read a transfer log strictly; :class:`BenchLogError` (file, line, reason) on any bad input."""
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise BenchLogError(path, None, f"cannot read the file: {exc}") from None
    lines = text.split("\n")
    if lines[0].rstrip("\r") != MAGIC:
        raise BenchLogError(path, 1, f"the first line must be {MAGIC!r}, got {lines[0][:60]!r}")
    if len(lines) < 2 or not lines[1].startswith("# meta: "):
        raise BenchLogError(path, 2, "the second line must be '# meta: ' followed by a JSON object")
    try:
        meta = json.loads(lines[1][len("# meta: "):])
    except json.JSONDecodeError as exc:
        raise BenchLogError(path, 2, f"bad JSON in the meta line: {exc}") from None
    if not isinstance(meta, dict):
        raise BenchLogError(path, 2, "the meta line must hold a JSON object")
    for key in REQUIRED_META:
        if key not in meta:
            raise BenchLogError(path, 2, f"the meta line lacks the required key {key!r}")
    n = 2
    while n < len(lines) and lines[n].startswith("#"):
        n += 1
    if n >= len(lines) or not lines[n].strip():
        raise BenchLogError(path, n + 1, "no column row")
    header = lines[n].rstrip("\r").split(",")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise BenchLogError(path, n + 1, f"missing column(s) {', '.join(missing)}")
    if len(set(header)) != len(header):
        raise BenchLogError(path, n + 1, "a column name appears twice")
    col = {c: header.index(c) for c in header}
    body = lines[n + 1:]
    if body and body[-1] == "":
        body = body[:-1]
    cols = {c: [] for c in header}
    for j, line in enumerate(body, start=n + 2):
        fields = line.rstrip("\r").split(",")
        if len(fields) != len(header):
            cut = j == n + 1 + len(body) and not text.endswith("\n")
            raise BenchLogError(path, j, f"{len(fields)} fields for {len(header)} columns"
                                + (" (the last line is cut short)" if cut else ""))
        row = {}
        for c in header:
            v = fields[col[c]].strip()
            if c == "setup":
                if not v:
                    raise BenchLogError(path, j, "empty setup name")
                row[c] = v
            elif c in ("drive_plus", "drive_minus", "meas_plus", "meas_minus"):
                if not v.isdigit() or int(v) < 1:
                    raise BenchLogError(path, j, f"{c} must be an electrode number >= 1, got {v!r}")
                row[c] = int(v)
            else:
                try:
                    x = float(v)
                except ValueError:
                    raise BenchLogError(path, j, f"{c} is not a number: {v!r}") from None
                if not math.isfinite(x):
                    raise BenchLogError(path, j, f"{c} is not finite: {v!r}")
                row[c] = x
        if row["drive_plus"] == row["drive_minus"]:
            raise BenchLogError(path, j, f"drive pair joins electrode {row['drive_plus']} to itself")
        if row["meas_plus"] == row["meas_minus"]:
            raise BenchLogError(path, j, f"measurement pair joins electrode {row['meas_plus']} to itself")
        if not row["I_A"] > 0:
            raise BenchLogError(path, j, f"I_A must be > 0 (the current driven from drive_plus), got {row['I_A']}")
        for c in header:
            cols[c].append(row[c])
    if not body:
        raise BenchLogError(path, None, "no data rows")
    extra = {c: np.asarray(v) for c, v in cols.items() if c not in COLUMNS}
    return TransferLog(path, meta, np.asarray(cols["setup"], dtype=object),
                       np.stack([cols["drive_plus"], cols["drive_minus"]], axis=1).astype(np.int64),
                       np.stack([cols["meas_plus"], cols["meas_minus"]], axis=1).astype(np.int64),
                       np.asarray(cols["V_V"], float), np.asarray(cols["I_A"], float), extra)
