"""Fault injection for the virtual bench: what goes wrong on a serial line.

=============  =================================================================
kind           what the virtual bench does at a random sample
=============  =================================================================
corrupt        sends the record with one digit changed (its CRC no longer matches)
drop           does not send the record (its sequence number is skipped)
garbage        sends a burst of random bytes before the record, ending the burst
               with a line end or not (then it sticks to the record's front)
disconnect     the port disappears (the pseudo-terminal or the socket is closed)
               for ``disconnect_s`` and comes back; records produced until the
               host talks again are lost
restart        the device reboots: new boot number, sequence and clock from 0,
               a hello line, and it waits for START
=============  =================================================================

A plan is text: ``corrupt=3,drop=2,garbage=2,disconnect=1,restart=1`` (counts
over the run), ``all`` (three of each line fault, one disconnect and one restart), or
``none``.

Example
-------
>>> from electrosense.validation.bench.virtual.faults import FaultPlan
>>> plan = FaultPlan.parse("corrupt=2,restart=1")
>>> sorted(k for ks in plan.schedule(50, seed=1).values() for k in ks)
['corrupt', 'corrupt', 'restart']
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FaultPlan", "FAULT_KINDS"]

FAULT_KINDS = ("corrupt", "drop", "garbage", "disconnect", "restart")
_ALL = {"corrupt": 3, "drop": 3, "garbage": 3, "disconnect": 1, "restart": 1}


@dataclass(frozen=True)
class FaultPlan:
    """How many faults of each kind, and how long a disconnection lasts."""

    counts: dict = field(default_factory=dict)
    disconnect_s: float = 1.0

    @classmethod
    def parse(cls, text: str | None, disconnect_s: float = 1.0) -> "FaultPlan":
        if text is None or text.strip() in ("", "none"):
            return cls({}, disconnect_s)
        if text.strip() == "all":
            return cls(dict(_ALL), disconnect_s)
        counts = {}
        for item in text.split(","):
            kind, sep, value = item.partition("=")
            kind = kind.strip()
            if kind not in FAULT_KINDS:
                raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULT_KINDS)} (or all, none)")
            try:
                n = int(value) if sep else 1
            except ValueError:
                raise ValueError(f"fault {item!r}: the count must be an integer") from None
            if n < 0:
                raise ValueError(f"fault {item!r}: the count must be >= 0")
            counts[kind] = counts.get(kind, 0) + n
        return cls(counts, disconnect_s)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def schedule(self, n_samples: int, seed=None) -> dict[int, list[str]]:
        """Sample index -> faults at that sample, on distinct samples.

        Restarts fall in the second quarter of the run and disconnections in
        the third (so that the host sees the line come back and the records go
        on, and a restart does not hide the records lost while the line was
        down); line faults anywhere but the first and last two samples.
        """
        if self.total == 0:
            return {}
        rng = np.random.default_rng(seed)
        taken: dict[int, list[str]] = {}
        q = n_samples // 4
        for kinds, lo, hi in ((("restart",), q, 2 * q), (("disconnect",), 2 * q, 3 * q),
                              (("corrupt", "drop", "garbage"), 2, n_samples - 2)):
            wanted = [k for k in kinds for _ in range(self.counts.get(k, 0))]
            slots = np.setdiff1d(np.arange(lo, hi), list(taken))
            if len(slots) < len(wanted):
                raise ValueError(f"{self.total} faults do not fit in a run of {n_samples} samples")
            chosen = rng.choice(slots, size=len(wanted), replace=False)
            taken.update({int(i): [k] for i, k in zip(chosen, wanted)})
        return taken

    def describe(self) -> str:
        text = ", ".join(f"{k}={v}" for k, v in self.counts.items() if v) or "none"
        return text if "disconnect" not in self.counts else f"{text} (disconnections of {self.disconnect_s:g} s)"
