"""The acquisition loop: serial line in, bench log out, nothing lost.

Every line the device sends ends up either in the bench log (a checked,
in-sequence record) or in the side file ``<log>.rejected`` (with the reason
and the bytes as received, escaped). Gaps in the sequence, device restarts and
port losses are counted, shown live and written to the side file as events.
The log is written append-only through
:class:`~validation.bench.log.BenchLogWriter`: flushed at every record, synced
to the disk within half a second.

Any pyserial URL serves as the port: a device path, a pseudo-terminal,
``socket://host:port``, ``loop://``.

Times: ``t_s`` in the log is the device's time. When a device restarts (its
clock starts again from 0) or a log is appended to, the device's time would go
backwards; the logger then adds an offset so that ``t_s`` continues from the
last logged time plus the time the host saw pass, and writes the offset as an
event in the side file. The device's ``boot`` and ``seq`` numbers are logged
as two extra columns.

Example
-------
>>> from electrosense.validation.bench.logger.logger import Logger
>>> meta = {"sensor": "angels-4", "emitter": 4, "tank_m": [1, 1, 1], "sigma_S_per_m": 0.0354}
>>> summary = Logger("socket://127.0.0.1:7000", "run.csv", meta, samples=100).run()   # doctest: +SKIP
>>> print(summary.text())                                                              # doctest: +SKIP
"""
from __future__ import annotations

import codecs
import datetime as _dt
import sys
import threading
import time
from dataclasses import dataclass
from dataclasses import fields as dc_fields
from pathlib import Path

from electrosense.validation.bench.log import BenchLogWriter, standard_columns
from electrosense.validation.bench.log.header import check_columns, interpret_meta
from electrosense.validation.bench.logger.protocol import (
    Ack,
    DataRecord,
    FrameError,
    Hello,
    SequenceTracker,
    encode_command,
    parse_line,
)

__all__ = ["Logger", "AcquisitionCounters", "AcquisitionSummary", "rejected_path", "MAX_LINE_BYTES"]

#: A "line" longer than this without a line end is noise: it is cut and rejected.
MAX_LINE_BYTES = 4096
EXTRA_COLUMNS = ("boot", "seq")


def rejected_path(log_path) -> Path:
    """The side file of a log: ``<log>.rejected``."""
    p = Path(log_path)
    return p.with_name(p.name + ".rejected")


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def _escaped(raw: bytes) -> str:
    """Bytes as printable ASCII, losslessly (\\r, \\n, \\t, \\xNN escapes)."""
    return codecs.escape_encode(raw)[0].decode("ascii")


@dataclass
class AcquisitionCounters:
    """What happened on the line since the logger started."""

    records: int = 0      #: records written to the log
    corrupt: int = 0      #: lines whose checksum did not match
    framing: int = 0      #: lines without start marker or checksum, or with a malformed content
    garbage: int = 0      #: bursts of noise found before a start marker
    refused: int = 0      #: checked records the log could not take (field count, values, time)
    duplicates: int = 0   #: records received twice (same boot and seq)
    gaps: int = 0         #: jumps in the sequence
    missing: int = 0      #: records never received intact (sum of the gaps)
    missing_while_down: int = 0  #: of ``missing``: records the device sent while no logger ran (``append``)
    incomplete: int = 0   #: lines cut short by a lost port or the end of the acquisition
    restarts: int = 0     #: device restarts (new boot number)
    reconnects: int = 0   #: times the port was lost and opened again
    after_stop: int = 0   #: complete lines read with the last chunk after the stop condition (side file only)

    @property
    def rejected(self) -> int:
        """Lines (or fragments) kept in the side file instead of the log."""
        return self.corrupt + self.framing + self.garbage + self.refused + self.duplicates + self.incomplete

    def as_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dc_fields(self)}
        d["rejected"] = self.rejected
        return d


@dataclass
class AcquisitionSummary:
    log_path: Path
    rejected_path: Path
    counters: AcquisitionCounters
    seconds: float
    device: str
    stopped_by: str
    resumed: str = ""  #: with ``append``: how the new records follow the log's last one

    def text(self) -> str:
        c = self.counters
        down = f", {c.missing_while_down} of them while the logger was down" if c.missing_while_down else ""
        lines = [
            f"{c.records} records written to {self.log_path} in {self.seconds:.1f} s (stopped by {self.stopped_by})",
            f"device: {self.device}",
            f"rejected {c.rejected}: checksum {c.corrupt}, framing {c.framing}, noise {c.garbage}, "
            f"refused {c.refused}, duplicates {c.duplicates}, cut short {c.incomplete}",
            f"sequence: {c.gaps} gaps ({c.missing} records missing{down}), {c.restarts} device restarts, "
            f"{c.reconnects} reconnects",
        ]
        if self.resumed:
            lines.append(self.resumed)
        if c.after_stop:
            lines.append(f"{c.after_stop} lines received after the stop condition kept in the side file, not logged")
        if c.rejected or c.gaps or c.restarts or c.reconnects or c.after_stop:
            lines.append(f"details: {self.rejected_path}")
        return "\n".join(lines)


class _PortLost(Exception):
    pass


class Logger:
    """Acquire records from a serial line into a bench log.

    Parameters
    ----------
    port : str
        Any pyserial URL or device path.
    log_path : str or Path
        The bench log to write; refused if it exists, unless ``append``.
    meta : dict
        Meta object of the log (sensor, emitter, tank_m, sigma_S_per_m, ...).
        ``device`` (from the device's hello) and ``started`` are added, and
        ``source`` if not given.
    baudrate : int
    samples : int, optional
        Stop after this many records written.
    seconds : float, optional
        Stop after this many seconds.
    append : bool
        Go on with an existing log of the same run.
    quiet : bool
        No live status line.
    status : file
        Where the status line goes (default stderr). On a terminal it is one
        line updated in place (at most 4 times a second); otherwise (a file,
        a pipe, a CI log) a full line every ``status_interval_s``.
    status_interval_s : float
        Seconds between two status lines when ``status`` is not a terminal.
    fields : sequence of str, optional
        Field names of a record, for a device that does not answer ``ID``;
        default: the hello's fields, or the spec's columns for the sensor.
    identify_timeout_s : float
        How long to wait for the hello before using the default fields.
    reconnect_interval_s : float
        Pause between attempts to open a lost port.
    stop : threading.Event, optional
        Set it to stop the loop (from another thread).
    start_device : bool
        Send ``START`` after the identification (and after a restart).
    voltage_V : float, optional
        Ask the device for this emitter voltage (``VOLT``) before each ``START``.
    """

    def __init__(self, port: str, log_path, meta: dict, baudrate: int = 115200, samples: int | None = None,
                 seconds: float | None = None, append: bool = False, quiet: bool = False, status=None,
                 fields=None, identify_timeout_s: float = 2.0, reconnect_interval_s: float = 0.5,
                 read_timeout_s: float = 0.05, sync_interval_s: float = 0.5, stop: threading.Event | None = None,
                 start_device: bool = True, voltage_V: float | None = None, status_interval_s: float = 5.0):
        self.port_url = str(port)
        self.log_path = Path(log_path)
        self.rejected_path = rejected_path(self.log_path)
        self.meta = dict(meta)
        if self.log_path.exists() and not append:     # the user's file first: nothing else matters then
            raise FileExistsError(f"{self.log_path} exists; refusing to overwrite a bench log (use append)")
        self.header = interpret_meta(self.meta, self.log_path, folder=self.log_path.parent)
        self.baudrate = int(baudrate)
        self.samples, self.seconds = samples, seconds
        self.append, self.quiet = append, quiet
        self.status = sys.stderr if status is None else status
        try:
            self._status_tty = bool(self.status.isatty())
        except (AttributeError, ValueError, OSError):
            self._status_tty = False
        self.status_interval_s = float(status_interval_s)
        self.fields = tuple(fields) if fields is not None else None
        self.identify_timeout_s = identify_timeout_s
        self.reconnect_interval_s = reconnect_interval_s
        self.read_timeout_s = read_timeout_s
        self.sync_interval_s = sync_interval_s
        self.stop = stop or threading.Event()
        self.start_device = start_device
        self.voltage_V = voltage_V
        if voltage_V is not None:
            self.meta.setdefault("voltage_V", float(voltage_V))
        self.counters = AcquisitionCounters()
        self.device = "unknown (no hello received)"
        self.last_currents: tuple[str, ...] = ()
        self._writer: BenchLogWriter | None = None
        self._side = None
        self._tracker = SequenceTracker()
        self._pending: list[DataRecord] = []
        self._offset_s = 0.0
        self._offset_boot: int | None = None
        self._last_write_host = None
        self._port = None
        self._status_shown = 0.0
        self._status_len = 0
        self._stop_reason_text: str | None = None
        self._resume: tuple[int, int] | None = None  # (boot, seq) of the log's last record, when appending
        self._resumed_text = ""

    def request_stop(self, reason: str = "stop request") -> None:
        """Stop the loop at its next turn (safe from a signal handler or another thread)."""
        self._stop_reason_text = reason
        self.stop.set()

    # ------------------------------------------------------------- side file
    def _side_write(self, reason: str, raw: bytes = b"") -> None:
        if self._side is None:
            new = not self.rejected_path.exists()
            self._side = open(self.rejected_path, "ab", buffering=0)
            if new:
                self._side.write((f"# esense acquire: what was received on {self.port_url} but not written to "
                                  f"{self.log_path.name}, and events; host time (UTC) TAB reason TAB line as "
                                  f"received (escaped)\n").encode())
        self._side.write(f"{_now_iso()}\t{reason}\t{_escaped(raw)}\n".encode("ascii", "backslashreplace"))

    def _reject(self, counter: str, reason: str, raw: bytes) -> None:
        setattr(self.counters, counter, getattr(self.counters, counter) + 1)
        self._side_write(reason, raw)

    def _event(self, text: str) -> None:
        self._side_write("event: " + text)

    # ------------------------------------------------------------------ port
    def _open(self):
        import serial

        port = serial.serial_for_url(self.port_url, baudrate=self.baudrate, timeout=self.read_timeout_s,
                                     write_timeout=1.0)
        self._port = port
        self._send("ID")
        if self._writer is not None:
            self._start()
        return port

    def _start(self) -> None:
        """Set the voltage if asked, then start the device's stream."""
        if not self.start_device:
            return
        if self.voltage_V is not None:
            self._send("VOLT", f"{self.voltage_V:.6f}")
        self._send("START")

    def _send(self, name: str, *args) -> None:
        try:
            self._port.write(encode_command(name, *args))
        except Exception:  # a lost port shows up on the next read
            pass

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except Exception:
                pass
            self._port = None

    def _reconnect(self, t0: float) -> bool:
        """Wait for the port to come back; False if told to stop meanwhile."""
        import serial

        self._close_port()
        lost_at = time.monotonic()
        self._event(f"port {self.port_url} lost; waiting for it")
        while not self._should_stop(t0):
            self._show_status(t0, waiting=True)
            time.sleep(self.reconnect_interval_s)
            try:
                self._open()
            except (serial.SerialException, OSError, ValueError):
                continue
            self.counters.reconnects += 1
            self._event(f"port {self.port_url} back after {time.monotonic() - lost_at:.1f} s")
            return True
        return False

    # ---------------------------------------------------------------- writing
    def _create_writer(self, fields: tuple[str, ...]) -> None:
        columns = tuple(fields) + tuple(c for c in EXTRA_COLUMNS if c not in fields)
        try:
            check_columns(list(columns), self.header, self.log_path, 3)
        except ValueError as exc:
            reason = getattr(exc, "reason", str(exc))
            raise ValueError(f"the device's record fields ({';'.join(fields)}) do not fit the log's meta "
                             f"(sensor {self.meta['sensor']}, emitter {self.header.emitter}): {reason}") from None
        meta = dict(self.meta)
        meta.setdefault("source", f"esense acquire from {self.port_url}; device: {self.device}")
        meta["device"] = self.device
        meta.setdefault("started", _now_iso())
        self._writer = BenchLogWriter(self.log_path, meta, columns=columns, append=self.append,
                                      sync_interval_s=self.sync_interval_s)
        self._columns = self._writer.columns
        self._n_fields = len(fields)
        if self._writer.recovered_tail is not None:
            self._side_write("cut-short last line removed from the log before appending",
                             self._writer.recovered_tail.encode("utf-8", "backslashreplace"))
        if self.append:
            self._resume_sequence()
        self._start()
        pending, self._pending = self._pending, []
        for record in pending:
            self._take_record(record, raw=None)

    def _resume_sequence(self) -> None:
        """Appending: go on from the (boot, seq) of the log's last record, so that what was lost counts.

        Records the device sent while no logger ran show up as a gap before
        the first new record of the same boot; another boot (announced by the
        hello or by the first record) is a restart of the device.
        """
        last = self._writer.last_row
        if not last or "boot" not in last or "seq" not in last:
            self._resumed_text = "appending: the log's last record has no boot/seq; losses before now are unknown"
            return
        try:
            boot, seq = int(last["boot"]), int(last["seq"])
        except ValueError:
            self._resumed_text = (f"appending: the log's last record has boot {last['boot']!r} seq {last['seq']!r}; "
                                  "losses before now are unknown")
            return
        self._resume = (boot, seq)
        self._resumed_text = f"appending after the log's last record: boot {boot} seq {seq}"
        announced = self._tracker.boot
        if announced is not None and announced != boot:
            self.counters.restarts += 1
            self._resumed_text += f"; the device restarted meanwhile (now boot {announced})"
            self._event(f"device restarted since the log's last record: boot {boot} -> {announced} (records sent "
                        f"by boot {boot} after seq {seq} are unknown)")
        else:
            self._tracker.boot, self._tracker.seq = boot, seq

    def _shifted(self, text: str, offset: float) -> str:
        """``text`` (a time in s) plus ``offset``, with as many decimals as the device wrote."""
        value = float(text) + offset
        if "." in text and "e" not in text.lower():
            return f"{value:.{len(text.split('.')[1])}f}"
        return repr(value)

    def _take_record(self, record: DataRecord, raw: bytes | None) -> None:
        raw = raw if raw is not None else f"(record boot {record.boot} seq {record.seq})".encode()
        if self._writer is None:
            self._pending.append(record)
            return
        if len(record.values) != self._n_fields:
            self._reject("refused", f"refused: {len(record.values)} values, the device's fields are {self._n_fields}",
                         raw)
            return
        event, n = self._tracker.feed(record.boot, record.seq)
        if event == "duplicate":
            self._reject("duplicates", f"duplicate: record boot {record.boot} seq {record.seq} already received", raw)
            return
        if event == "restart":
            self.counters.restarts += 1
            self._event(f"device restarted: boot {record.boot} (records start again at seq {record.seq})")
        elif event == "gap":
            self.counters.gaps += 1
            self.counters.missing += n
            down = ""
            if self._resume is not None and self.counters.records == 0 and self._resume[0] == record.boot:
                self.counters.missing_while_down += n
                down = " (sent while the logger was down, after the log's last record)"
            self._event(f"gap: {n} record{'s' if n > 1 else ''} missing before boot {record.boot} seq {record.seq}"
                        + down)
        if event == "restart" and self._resume is not None and self.counters.records == 0:
            self._resumed_text += f"; the device restarted meanwhile (now boot {record.boot})"
        values = list(record.values)
        t_index = self._columns.index("t_s")
        if record.boot != self._offset_boot:
            self._offset_boot = record.boot
            last = self._writer.last_t_s
            try:
                t_dev = float(values[t_index])
            except ValueError:
                t_dev = None
            if last is not None and t_dev is not None and t_dev + self._offset_s < last:
                host_gap = 0.0 if self._last_write_host is None else time.monotonic() - self._last_write_host
                self._offset_s = last + host_gap - t_dev
                self._event(f"device time restarted: t_s of boot {record.boot} offset by {self._offset_s:+.6f} s "
                            f"(device time + offset = logged t_s)")
        if self._offset_s:
            try:
                values[t_index] = self._shifted(values[t_index], self._offset_s)
            except ValueError:
                pass  # the writer refuses it below, with the reason
        try:
            self._writer.write(values + [str(record.boot), str(record.seq)])
        except ValueError as exc:
            self._reject("refused", f"refused: {exc}", raw)
            return
        self._last_write_host = time.monotonic()
        self.counters.records += 1
        currents = [values[i] for i, c in enumerate(self._columns[:self._n_fields]) if c.startswith("I")]
        self.last_currents = tuple(currents)

    def _handle_line(self, raw: bytes) -> None:
        if raw.strip() == b"":
            return
        try:
            noise, message = parse_line(raw)
        except FrameError as exc:
            self._reject("corrupt" if exc.kind == "checksum" else "framing", f"{exc.kind}: {exc.reason}", raw)
            return
        if noise:
            self._reject("garbage", "noise before the start marker (the record after it was kept)", noise)
        if isinstance(message, Hello):
            self.device = message.device
            if self._tracker.note_hello(message.boot):
                self.counters.restarts += 1
                self._event(f"device restarted: hello with boot {message.boot}")
                if self._resume is not None and self.counters.records == 0:
                    self._resumed_text += f"; the device restarted meanwhile (now boot {message.boot})"
                if self._writer is not None:
                    self._start()
            if self._writer is None:
                self._create_writer(self.fields or message.fields)
            elif tuple(message.fields) != tuple(self._columns[:self._n_fields]):
                self._event(f"device announces other fields ({';'.join(message.fields)}) than the log's columns")
        elif isinstance(message, Ack):
            if not message.ok:
                self._event(f"device refused {message.command}: {message.text}")
        elif isinstance(message, DataRecord):
            self._take_record(message, raw)

    # ----------------------------------------------------------------- status
    def _should_stop(self, t0: float) -> bool:
        if self.stop.is_set():
            return True
        if self.samples is not None and self.counters.records >= self.samples:
            return True
        return self.seconds is not None and time.monotonic() - t0 >= self.seconds

    def status_text(self, t0: float, waiting: bool = False) -> str:
        c = self.counters
        dt = max(time.monotonic() - t0, 1e-9)
        text = (f"{c.records} records  {c.records / dt:.1f}/s  rejected {c.rejected} "
                f"(crc {c.corrupt}, framing {c.framing}, noise {c.garbage})  gaps {c.gaps} ({c.missing} missing)  "
                f"restarts {c.restarts}  reconnects {c.reconnects}")
        if waiting:
            text += f"  WAITING FOR {self.port_url}"
        elif self.last_currents:
            text += "  I/A " + " ".join(self.last_currents)
        return text

    def _show_status(self, t0: float, waiting: bool = False, force: bool = False) -> None:
        """The live status: updated in place on a terminal, a line every ``status_interval_s`` elsewhere."""
        if self.quiet:
            return
        now = time.monotonic()
        interval = 0.25 if self._status_tty else self.status_interval_s
        if not self._status_tty and not self._status_shown:
            self._status_shown = now  # the first line after one interval, not "0 records" at once
        if not force and now - self._status_shown < interval:
            return
        self._status_shown = now
        text = self.status_text(t0, waiting)
        if self._status_tty:
            pad = max(0, self._status_len - len(text))
            self._status_len = len(text)
            self.status.write("\r" + text + " " * pad)
        else:
            self.status.write(f"[{now - t0:7.1f} s] {text}\n")
        self.status.flush()

    # ------------------------------------------------------------------- loop
    def run(self) -> AcquisitionSummary:
        """Acquire until ``samples``, ``seconds``, ``stop`` or Ctrl-C; return the summary."""
        import serial

        t0 = time.monotonic()
        stopped_by = "error"
        try:
            self._open()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise OSError(f"cannot open the port {self.port_url}: {exc}") from None
        if self.fields is not None:
            self.device = "unknown (fields given by the user)"
            self._create_writer(self.fields)
        buffer = b""
        try:
            while not self._should_stop(t0):
                try:
                    if self._port is None:
                        raise _PortLost()
                    chunk = self._port.read(max(1, self._port.in_waiting))
                except (serial.SerialException, OSError, _PortLost):
                    if buffer:
                        self._reject("incomplete", "incomplete line when the port was lost", buffer)
                        buffer = b""
                    if not self._reconnect(t0):
                        break
                    continue
                if chunk:
                    buffer += chunk
                    *lines, buffer = buffer.split(b"\n")
                    for k, line in enumerate(lines):
                        if self._should_stop(t0):  # complete lines already read: kept aside, not lost
                            for rest in lines[k:]:
                                self.counters.after_stop += 1
                                self._side_write("received after the stop condition, not logged", rest + b"\n")
                            break
                        self._handle_line(line + b"\n")
                    if len(buffer) > MAX_LINE_BYTES:
                        self._reject("framing", f"no line end within {MAX_LINE_BYTES} bytes", buffer)
                        buffer = b""
                if self._writer is None and time.monotonic() - t0 > self.identify_timeout_s:
                    self._event(f"no hello within {self.identify_timeout_s} s: using the spec's columns for "
                                f"{self.meta['sensor']}")
                    self._create_writer(standard_columns(self.header.sensor))
                if self._writer is not None:
                    self._writer.sync_if_due()
                self._show_status(t0)
            stopped_by = self._stop_reason(t0)
        except KeyboardInterrupt:
            stopped_by = "interrupt (Ctrl-C)"
        finally:
            if buffer:
                self._reject("incomplete", "incomplete line at the end of the acquisition", buffer)
            if self._port is not None:
                self._send("STOP")
            self._close_port()
            if self._writer is None and self._pending:  # records came, but no hello: log them as the spec says
                try:
                    self._create_writer(self.fields or standard_columns(self.header.sensor))
                except (OSError, ValueError) as exc:
                    for record in self._pending:  # never lost: kept aside with the reason
                        self._reject("refused", f"refused: no log could be opened ({exc})",
                                     f"(record boot {record.boot} seq {record.seq}) {','.join(record.values)}".encode())
                    self._pending = []
            if self._writer is not None:
                self._writer.close()
            if not self.quiet:
                self._show_status(t0, force=True)
                if self._status_tty:
                    self.status.write("\n")
                self.status.flush()
            if self._side is not None:
                self._side.close()
        return AcquisitionSummary(self.log_path, self.rejected_path, self.counters, time.monotonic() - t0,
                                  self.device, stopped_by, self._resumed_text)

    def _stop_reason(self, t0: float) -> str:
        if self.samples is not None and self.counters.records >= self.samples:
            return f"{self.samples} samples"
        if self.seconds is not None and time.monotonic() - t0 >= self.seconds:
            return f"{self.seconds} s"
        return self._stop_reason_text or "stop request"
