"""The virtual bench's firmware: streams a simulated run over the serial protocol, with faults.

It behaves as the real bench's firmware should (docs/serial-protocol.md): a
hello at power-up and on ``ID``; records ``$D,boot,seq,...`` at the chosen
rate once started; ``START``, ``STOP`` and ``VOLT`` obeyed and acknowledged.
The sequence number counts every record produced, sent or not, so that a
host sees lost records as gaps; after a restart boot, sequence and clock begin
again.

What really happened to every sample can be written to a *truth* file (a
bench log labelled as simulated) with the columns ``boot``, ``seq``,
``t_device_s``, the true pose and conductivity, ``fate`` (``sent``,
``corrupt``, ``dropped``, ``disconnected``, ``unsent``, ``unheard``) and
``noise`` (``line`` or ``prefix`` when garbage bytes came before it): the
tests check a logger against it. ``unheard`` is a record an ``autostart``
device wrote to a host that had not yet said anything on the line: whether
it was read depends on when the host's port finished opening (opening a port
flushes what waits in it), so a host may or may not have it.

Example
-------
>>> device = BenchDevice(run, PtyTransport(), rate_hz=20, faults=FaultPlan.parse("all"))   # doctest: +SKIP
>>> report = device.serve()                                                                 # doctest: +SKIP
"""
from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from electrosense.validation.bench.log import BenchLogWriter
from electrosense.validation.bench.logger.protocol import (
    FrameError,
    encode_ack,
    encode_hello,
    encode_record,
    parse_command,
)
from electrosense.validation.bench.virtual.bench import SimulatedRun
from electrosense.validation.bench.virtual.faults import FaultPlan
from electrosense.validation.bench.virtual.transport import NoHost

__all__ = ["BenchDevice", "DeviceReport", "TRUTH_COLUMNS"]

TRUTH_COLUMNS = ("boot", "seq", "t_device_s", "x_true_m", "y_true_m", "z_true_m", "yaw_true_rad",
                 "sigma_true_S_per_m", "fate", "noise")
_GARBAGE = np.array(sorted(set(range(256)) - set(b"$\r\n")), dtype=np.uint8)


@dataclass
class DeviceReport:
    """What the device did: counts of fates and faults."""

    fates: Counter = field(default_factory=Counter)
    faults: Counter = field(default_factory=Counter)
    boots: list = field(default_factory=list)

    def text(self) -> str:
        fates = ", ".join(f"{k} {v}" for k, v in sorted(self.fates.items())) or "none"
        faults = ", ".join(f"{k} {v}" for k, v in sorted(self.faults.items())) or "none"
        return f"records: {fates}; faults injected: {faults}; boots {len(self.boots)}"


class BenchDevice:
    """Serve a :class:`SimulatedRun` on a transport, as the bench's firmware would.

    Parameters
    ----------
    run : SimulatedRun
    transport : PtyTransport or SocketTransport
    rate_hz : float
        Records per second.
    faults : FaultPlan
    seed : int, optional
        Fault positions, boot numbers, garbage bytes.
    name : str
        Device name in the hello line (always says it is a simulator).
    autostart : bool
        Stream without waiting for ``START``.
    truth_path : path, optional
        Write the truth file there (refused if it exists).
    truth_meta : dict, optional
        Meta of the truth file (sensor, emitter, tank_m, sigma_S_per_m, ...).
    say : callable, optional
        Progress messages (e.g. ``print`` to stderr).
    """

    def __init__(self, run: SimulatedRun, transport, rate_hz: float = 10.0, faults: FaultPlan = FaultPlan(),
                 seed=None, name: str = "esense bench-sim (SIMULATOR)", autostart: bool = False,
                 truth_path=None, truth_meta: dict | None = None, say=None):
        self.run, self.transport, self.rate_hz = run, transport, float(rate_hz)
        self.faults = faults
        self.rng = np.random.default_rng(seed)
        self.name = name if "SIMULAT" in name.upper() else f"{name} (SIMULATOR)"
        self.autostart = autostart
        self.say = say or (lambda text: None)
        self.schedule = faults.schedule(len(run), seed=self.rng.integers(2**32))
        self.report = DeviceReport()
        self._truth = None
        if truth_path is not None:
            meta = dict(truth_meta or {})
            meta["source"] = (f"{run.info.get('description', 'esense bench-sim: SIMULATED data')}; faults: "
                              f"{faults.describe()}; truth file of the virtual bench")
            self._truth = BenchLogWriter(truth_path, meta, columns=run.columns + TRUTH_COLUMNS)
        self.U_V = float(run.U_V[0]) if len(run) else 1.0
        self._boot()

    # ----------------------------------------------------------------- state
    def _boot(self) -> None:
        self.boot = int(self.rng.integers(1, 2**31))
        self.seq = 0
        self.since_boot = 0  # samples produced since power-up: the device clock is since_boot / rate
        self.started = self.autostart
        self.host_ready = self.autostart
        self.report.boots.append(self.boot)

    def _send(self, data: bytes) -> bool:
        try:
            self.transport.write(data)
            return True
        except (NoHost, OSError):
            self.host_ready = self.autostart and self.transport.connected
            return False

    def _hello(self) -> None:
        self._send(encode_hello(self.boot, self.name, self.run.columns))

    def _commands(self, buffer: bytes) -> bytes:
        """Obey the complete command lines in ``buffer``; return the rest."""
        *lines, rest = buffer.split(b"\n")
        for line in lines:
            if not line.strip():
                continue
            try:
                cmd = parse_command(line)
            except FrameError as exc:
                self._send(encode_ack("?", False, exc.kind))
                continue
            self.host_ready = True
            if cmd.name == "ID":
                self._hello()
            elif cmd.name == "START":
                self.started = True
                self._send(encode_ack("START", True))
            elif cmd.name == "STOP":
                self.started = False
                self._send(encode_ack("STOP", True))
            elif cmd.name == "VOLT":
                try:
                    value = float(cmd.args[0])
                    if not np.isfinite(value):
                        raise ValueError
                except (IndexError, ValueError):
                    self._send(encode_ack("VOLT", False, "expected VOLT,<U_V>"))
                    continue
                self.U_V = value
                self._send(encode_ack("VOLT", True, f"{value:.6f}"))
        return rest

    # --------------------------------------------------------------- records
    def _values(self, i: int) -> list[str]:
        values = self.run.record_values(i, t_s=self.since_boot / self.rate_hz)
        scale = self.U_V / float(self.run.U_V[i])
        if scale != 1.0:  # currents are linear in U
            n_rec = self.run.currents_A.shape[1]
            values[5] = f"{self.U_V:.6f}"
            values[6:6 + n_rec] = [f"{c * scale:.5e}" for c in self.run.currents_A[i]]
        return values

    def _corrupted(self, line: bytes) -> bytes:
        body_end = line.rindex(b"*")
        digits = [k for k in range(3, body_end) if chr(line[k]).isdigit()]
        k = int(self.rng.choice(digits))
        new = str((int(chr(line[k])) + 1 + int(self.rng.integers(9))) % 10).encode()
        return line[:k] + new + line[k + 1:]

    def _garbage(self) -> tuple[bytes, str]:
        burst = bytes(self.rng.choice(_GARBAGE, size=int(self.rng.integers(3, 40))))
        if self.rng.random() < 0.5:
            return burst + b"\n", "line"
        return burst, "prefix"

    def _truth_row(self, i: int, values: list[str], fate: str, noise: str) -> None:
        self.report.fates[fate] += 1
        if self._truth is None:
            return
        row = list(self.run.record_values(i))  # t_s on the run's own clock: never goes back
        measured = slice(5, 6 + self.run.currents_A.shape[1])  # U_V and the currents, as sent
        row[measured] = values[measured]
        x, y, z, yaw = self.run.true_poses[i]
        row += [str(self.boot), str(self.seq), values[0], f"{x:.7f}", f"{y:.7f}", f"{z:.7f}", f"{yaw:.7f}",
                f"{self.run.sigma_true_S_per_m[i]:.7g}", fate, noise or "-"]
        self._truth.write(row)

    # ------------------------------------------------------------------ loop
    def serve(self, stop: threading.Event | None = None, linger_s: float = 0.0) -> DeviceReport:
        """Stream the run (then keep answering commands for ``linger_s``); return the report."""
        stop = stop or threading.Event()
        period = 1.0 / self.rate_hz
        self._hello()
        buffer = b""
        down_until = None
        i, n = 0, len(self.run)
        next_due = time.monotonic()
        try:
            while i < n and not stop.is_set():
                buffer = self._commands(buffer + self.transport.read())
                now = time.monotonic()
                if down_until is not None and now >= down_until:
                    self.transport.reconnect()
                    self.say(f"bench-sim: line back at {self.transport.path}")
                    down_until = None
                if not self.started:
                    time.sleep(0.002)
                    next_due = time.monotonic()
                    continue
                if now < next_due:
                    time.sleep(min(next_due - now, 0.002))
                    continue
                faults = self.schedule.pop(i, [])
                if faults and not (self.host_ready and self.transport.connected and self.transport.heard):
                    # nobody listens: the fault would go unseen; it happens at the next sample instead
                    self.schedule.setdefault(i + 1, []).extend(faults)
                    faults = []
                if len(faults) > 1:  # one fault per sample; the others follow
                    self.schedule[i + 1] = faults[1:] + self.schedule.get(i + 1, [])
                    faults = faults[:1]
                if "restart" in faults:
                    self.report.faults["restart"] += 1
                    self._boot()
                    self.say(f"bench-sim: device restart (boot {self.boot})")
                    self._hello()
                    self.schedule[i] = [f for f in faults if f != "restart"]
                    continue
                if "disconnect" in faults:
                    self.report.faults["disconnect"] += 1
                    # the cable is pulled between two records, once the host has the last one:
                    # then "sent" in the truth file means received
                    self.transport.drain()
                    self.transport.disconnect()
                    self.host_ready = False
                    down_until = now + self.faults.disconnect_s
                    self.say(f"bench-sim: line down for {self.faults.disconnect_s:g} s")
                values = self._values(i)
                line = encode_record(self.boot, self.seq, values)
                noise = ""
                if not (self.host_ready and self.transport.connected):
                    fate = "disconnected"
                elif "drop" in faults:
                    fate = "dropped"
                    self.report.faults["drop"] += 1
                else:
                    if "garbage" in faults:
                        burst, noise = self._garbage()
                        self.report.faults["garbage"] += 1
                        if not self._send(burst):
                            noise = ""
                    if "corrupt" in faults:
                        line = self._corrupted(line)
                        self.report.faults["corrupt"] += 1
                    sent = self._send(line)
                    fate = ("corrupt" if "corrupt" in faults else "sent") if sent else "unsent"
                    if fate == "sent" and not self.transport.heard:
                        fate = "unheard"  # the host's port may have flushed it while opening
                self._truth_row(i, values, fate, noise)
                self.seq += 1
                self.since_boot += 1
                i += 1
                next_due += period
            end = time.monotonic() + linger_s
            while not stop.is_set() and time.monotonic() < end:
                buffer = self._commands(buffer + self.transport.read())
                time.sleep(0.01)
        finally:
            if self._truth is not None:
                self._truth.close()
        return self.report
