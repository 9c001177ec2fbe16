"""The bench's serial protocol (version 1): framed, checked ASCII lines.

Device to host::

    $D,<boot>,<seq>,<value 1>,...,<value N>*CCCC<CR><LF>    one record (one bench-log row)
    $H,<boot>,1,<device>,<field 1>;...;<field N>*CCCC<CR><LF>  hello: at power-up and in reply to ID
    $A,<command>,OK|ERR[,<text>]*CCCC<CR><LF>               reply to a host command

Host to device::

    $C,ID*CCCC   $C,START*CCCC   $C,STOP*CCCC   $C,VOLT,<U_V>*CCCC

``CCCC`` is the CRC-16/CCITT-FALSE (polynomial 0x1021, initial value
0xFFFF, no reflection, no final xor) of the bytes between ``$`` and ``*``, in
four upper-case hexadecimal digits. ``boot`` is a number the device draws at
power-up (random or a counter kept in EEPROM), ``seq`` counts the records
produced since then from 0, including records the device could not send.
The logger tells apart:

* a corrupt line: no ``$``, no ``*CCCC``, or a CRC that does not match;
* a dropped line: ``seq`` jumps forward (the gap is the number of missing records);
* a restarted device: a new ``boot`` (seq starts again from 0).

The full description, for firmware writers, is docs/serial-protocol.md.

Example
-------
>>> from electrosense.validation.bench.logger.protocol import encode_record, parse_line
>>> line = encode_record(7, 0, ["0.000", "-0.3800", "0.0000", "0.0000", "0.000000", "1.000000", "1.0314e-03"])
>>> line
b'$D,7,0,0.000,-0.3800,0.0000,0.0000,0.000000,1.000000,1.0314e-03*3765\\r\\n'
>>> parse_line(line)
(b'', DataRecord(boot=7, seq=0, values=('0.000', '-0.3800', '0.0000', '0.0000', '0.000000', '1.000000', '1.0314e-03')))
"""
from __future__ import annotations

import binascii
import re
from dataclasses import dataclass

__all__ = [
    "PROTOCOL_VERSION", "crc16", "frame", "encode_record", "encode_hello", "encode_ack", "encode_command",
    "parse_line", "parse_command", "DataRecord", "Hello", "Ack", "Command", "FrameError", "SequenceTracker",
    "SEQ_MODULUS", "COMMANDS",
]

PROTOCOL_VERSION = 1
START = b"$"
SEPARATOR = b"*"
SEQ_MODULUS = 2**32
COMMANDS = ("ID", "START", "STOP", "VOLT")
_CRC = re.compile(rb"[0-9A-F]{4}")
_TEXT_FORBIDDEN = set(",*$;\r\n")


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF); ``crc16(b"123456789") == 0x29B1``."""
    return binascii.crc_hqx(data, 0xFFFF)


def frame(body: str) -> bytes:
    """``$<body>*CCCC\\r\\n`` for an ASCII body without ``$``, ``*`` or line breaks."""
    raw = body.encode("ascii")
    if any(c in raw for c in (b"$"[0], b"*"[0], b"\r"[0], b"\n"[0])):
        raise ValueError(f"a frame body may not contain $, * or line breaks: {body!r}")
    return START + raw + SEPARATOR + f"{crc16(raw):04X}".encode() + b"\r\n"


def _check_text(name: str, value: str) -> str:
    if not value.isascii() or _TEXT_FORBIDDEN & set(value):
        raise ValueError(f"{name} {value!r} must be ASCII without , * $ ; or line breaks")
    return value


@dataclass(frozen=True)
class DataRecord:
    """One record: the device's boot number, its sequence number, the row's values as sent."""

    boot: int
    seq: int
    values: tuple[str, ...]


@dataclass(frozen=True)
class Hello:
    """The device's identification: boot number, protocol version, name, field names of a record."""

    boot: int
    protocol: int
    device: str
    fields: tuple[str, ...]


@dataclass(frozen=True)
class Ack:
    """The device's reply to a command."""

    command: str
    ok: bool
    text: str = ""


@dataclass(frozen=True)
class Command:
    """A host command (``ID``, ``START``, ``STOP``, ``VOLT`` with the voltage)."""

    name: str
    args: tuple[str, ...] = ()


class FrameError(ValueError):
    """A line that is not a valid message; ``kind`` is ``"framing"``, ``"checksum"`` or ``"content"``."""

    def __init__(self, kind: str, reason: str):
        self.kind = kind
        self.reason = reason
        super().__init__(f"{kind}: {reason}")


def encode_record(boot: int, seq: int, values) -> bytes:
    """A ``$D`` line; ``values`` are the row's fields as text, in the hello's field order."""
    for v in values:
        _check_text("value", v)
    return frame(",".join(["D", str(int(boot)), str(int(seq) % SEQ_MODULUS), *values]))


def encode_hello(boot: int, device: str, fields) -> bytes:
    """A ``$H`` line announcing the device and the fields of its records."""
    for f in fields:
        _check_text("field name", f)
    return frame(",".join(["H", str(int(boot)), str(PROTOCOL_VERSION), _check_text("device", device), ";".join(fields)]))


def encode_ack(command: str, ok: bool, text: str = "") -> bytes:
    parts = ["A", _check_text("command", command), "OK" if ok else "ERR"]
    if text:
        parts.append(_check_text("text", text))
    return frame(",".join(parts))


def encode_command(name: str, *args) -> bytes:
    """A host command line, e.g. ``encode_command("VOLT", "1.000")``."""
    if name not in COMMANDS:
        raise ValueError(f"unknown command {name!r}; known: {', '.join(COMMANDS)}")
    return frame(",".join(["C", name, *(_check_text("argument", str(a)) for a in args)]))


def _unframe(line: bytes) -> tuple[bytes, str]:
    """(bytes before the start marker, checked body)."""
    line = line.rstrip(b"\r\n")
    start = line.rfind(START)
    if start < 0:
        raise FrameError("framing", "no start marker '$'")
    prefix, rest = line[:start], line[start + 1:]
    star = rest.rfind(SEPARATOR)
    if star < 0 or not _CRC.fullmatch(rest[star + 1:]):
        raise FrameError("framing", "no checksum '*CCCC' at the end of the line")
    body, crc = rest[:star], int(rest[star + 1:], 16)
    if crc16(body) != crc:
        raise FrameError("checksum", f"CRC {crc:04X} does not match the line (expected {crc16(body):04X})")
    try:
        return prefix, body.decode("ascii")
    except UnicodeDecodeError:
        raise FrameError("content", "non-ASCII bytes in a checked line") from None


def _integer(text: str, what: str, limit: int | None = None) -> int:
    """A non-negative decimal integer (ASCII digits only), below ``limit`` when given."""
    if not (text.isascii() and text.isdigit()):
        raise FrameError("content", f"{what} {text!r} is not a non-negative integer")
    if limit is not None and (len(text) > len(str(limit)) or int(text) >= limit):
        raise FrameError("content", f"{what} {text} is out of range (0 .. 2^32-1)")
    return int(text)


def parse_line(line: bytes) -> tuple[bytes, DataRecord | Hello | Ack]:
    """Check and decode one device line.

    Returns ``(garbage, message)``: ``garbage`` is whatever preceded the start
    marker (line noise the logger keeps aside); raises :class:`FrameError`.
    """
    prefix, body = _unframe(line)
    parts = body.split(",")
    kind = parts[0]
    if kind == "D":
        if len(parts) < 4:
            raise FrameError("content", "a record needs boot, seq and values")
        return prefix, DataRecord(_integer(parts[1], "boot", SEQ_MODULUS), _integer(parts[2], "seq", SEQ_MODULUS),
                                  tuple(parts[3:]))
    if kind == "H":
        if len(parts) != 5:
            raise FrameError("content", f"a hello has 5 parts (H,boot,version,device,fields), found {len(parts)}")
        return prefix, Hello(_integer(parts[1], "boot", SEQ_MODULUS), _integer(parts[2], "protocol version"), parts[3],
                             tuple(parts[4].split(";")))
    if kind == "A":
        if len(parts) < 3 or parts[2] not in ("OK", "ERR"):
            raise FrameError("content", "a reply is A,<command>,OK|ERR[,text]")
        return prefix, Ack(parts[1], parts[2] == "OK", ",".join(parts[3:]))
    raise FrameError("content", f"unknown message type {kind!r}")


def parse_command(line: bytes) -> Command:
    """Decode a host command (device side); raises :class:`FrameError`."""
    _, body = _unframe(line)
    parts = body.split(",")
    if parts[0] != "C" or len(parts) < 2:
        raise FrameError("content", f"not a command: {body!r}")
    if parts[1] not in COMMANDS:
        raise FrameError("content", f"unknown command {parts[1]!r}")
    return Command(parts[1], tuple(parts[2:]))


class SequenceTracker:
    """Classify each record by its (boot, seq) against the previous one.

    ``feed`` returns ``("ok", 0)``, ``("gap", n_missing)``, ``("restart", 0)``
    (a new boot number: seq starts again), ``("duplicate", 0)`` (seq seen
    already in this boot, e.g. a repeated line), or ``("first", 0)``.

    Example
    -------
    >>> t = SequenceTracker()
    >>> [t.feed(5, s) for s in (0, 1, 4)] + [t.feed(9, 0)]
    [('first', 0), ('ok', 0), ('gap', 2), ('restart', 0)]
    """

    def __init__(self):
        self.boot: int | None = None
        self.seq: int | None = None

    def feed(self, boot: int, seq: int) -> tuple[str, int]:
        if self.boot is None or (boot == self.boot and self.seq is None):
            event = ("first", 0)
        elif boot != self.boot:
            event = ("restart", 0)
        else:
            step = (seq - self.seq) % SEQ_MODULUS
            if step == 0 or step > SEQ_MODULUS // 2:
                return ("duplicate", 0)  # not accepted: the state stays
            event = ("ok", 0) if step == 1 else ("gap", step - 1)
        self.boot, self.seq = boot, seq
        return event

    def note_hello(self, boot: int) -> bool:
        """A hello line: True if it announces a restart (another boot than the records so far)."""
        restarted = self.boot is not None and boot != self.boot
        if restarted:
            self.boot, self.seq = boot, None
        elif self.boot is None:
            self.boot = boot
        return restarted
