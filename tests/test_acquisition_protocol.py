"""Serial protocol: CRC, framing, every way a line can be refused, sequence tracking, --meta text."""
import pytest

from electrosense.validation.bench.logger.meta_option import parse_meta_option
from electrosense.validation.bench.logger.protocol import (
    Ack,
    DataRecord,
    FrameError,
    Hello,
    SequenceTracker,
    crc16,
    encode_ack,
    encode_command,
    encode_hello,
    encode_record,
    frame,
    parse_command,
    parse_line,
)


def test_crc_is_ccitt_false():
    assert crc16(b"123456789") == 0x29B1  # the catalogue check value of CRC-16/CCITT-FALSE
    assert crc16(b"") == 0xFFFF


def test_round_trips():
    values = ("0.100", "-0.3750", "0.0000", "0.0000", "0.000000", "1.000000", "1.03100e-03")
    assert parse_line(encode_record(42, 7, values)) == (b"", DataRecord(42, 7, values))
    fields = ("t_s", "x_m", "I1_A")
    assert parse_line(encode_hello(3, "bench v2", fields)) == (b"", Hello(3, 1, "bench v2", fields))
    assert parse_line(encode_ack("VOLT", True, "1.0")) == (b"", Ack("VOLT", True, "1.0"))
    assert parse_command(encode_command("VOLT", "2.5")).args == ("2.5",)
    assert parse_command(encode_command("ID")).name == "ID"
    # line end \n alone is accepted too; noise before the start marker is handed back
    line = encode_record(1, 2, ["0.0"]).replace(b"\r\n", b"\n")
    assert parse_line(b"\x00\xffnoise" + line) == (b"\x00\xffnoise", DataRecord(1, 2, ("0.0",)))


def test_every_single_digit_change_is_caught():
    line = encode_record(42, 7, ["0.100", "-0.3750", "1.03100e-03"])
    body_end = line.index(b"*")
    for k in range(1, body_end):
        c = chr(line[k])
        if c.isdigit():
            bad = line[:k] + str((int(c) + 3) % 10).encode() + line[k + 1:]
            with pytest.raises(FrameError) as info:
                parse_line(bad)
            assert info.value.kind == "checksum"


@pytest.mark.parametrize("line, kind, text", [
    (b"D,1,2,0.0*1234\r\n", "framing", "no start marker"),
    (b"$D,1,2,0.0\r\n", "framing", "no checksum"),
    (b"$D,1,2,0.0*12G4\r\n", "framing", "no checksum"),
    (frame("D,1"), "content", "a record needs boot, seq and values"),
    (frame("D,x,2,0.0"), "content", "boot 'x' is not a non-negative integer"),
    (frame("D,1,-2,0.0"), "content", "seq '-2' is not a non-negative integer"),
    (frame("Q,1"), "content", "unknown message type 'Q'"),
    (frame("H,1,1,dev"), "content", "a hello has 5 parts"),
    (frame("A,START,MAYBE"), "content", "A,<command>,OK|ERR"),
])
def test_malformed_lines(line, kind, text):
    with pytest.raises(FrameError) as info:
        parse_line(line)
    assert info.value.kind == kind and text in info.value.reason


def test_frame_refuses_what_would_break_framing():
    with pytest.raises(ValueError):
        frame("D,1,2,a*b")
    with pytest.raises(ValueError):
        encode_record(1, 2, ["1,2"])
    with pytest.raises(ValueError):
        encode_command("REBOOT")
    with pytest.raises(FrameError, match="unknown command"):
        parse_command(frame("C,REBOOT"))


def test_sequence_tracker_tells_gaps_restarts_and_duplicates():
    t = SequenceTracker()
    assert t.feed(5, 10) == ("first", 0)
    assert t.feed(5, 11) == ("ok", 0)
    assert t.feed(5, 11) == ("duplicate", 0)
    assert t.feed(5, 9) == ("duplicate", 0)
    assert t.feed(5, 15) == ("gap", 3)
    assert t.feed(8, 0) == ("restart", 0)
    assert t.feed(8, 1) == ("ok", 0)
    # a hello of a new boot is a restart; the first record after it is not a gap
    assert t.note_hello(9) is True and t.feed(9, 0) == ("first", 0)
    assert t.note_hello(9) is False
    # the 32-bit sequence number wraps without a false gap
    w = SequenceTracker()
    w.feed(1, 2**32 - 1)
    assert w.feed(1, 0) == ("ok", 0)


def test_meta_option():
    assert parse_meta_option("sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354") == {
        "sensor": "angels-4", "emitter": 4, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": 0.0354}
    assert parse_meta_option("tank=none,notes=a,b")["tank_m"] is None
    assert parse_meta_option("tank=none,notes=a,b")["notes"] == "a,b"
    with pytest.raises(ValueError, match="tank needs three lengths"):
        parse_meta_option("tank=1,1")
    with pytest.raises(ValueError, match="expected key=value"):
        parse_meta_option("angels-4")


def test_the_protocol_document_examples_are_valid_lines():
    from pathlib import Path

    doc = (Path(__file__).resolve().parent.parent / "docs" / "serial-protocol.md").read_text()
    lines = [ln.strip() for ln in doc.splitlines() if ln.startswith(("$H,", "$D,"))]
    assert len(lines) == 2
    _, hello = parse_line(lines[0].encode())
    _, record = parse_line(lines[1].encode())
    assert isinstance(hello, Hello) and isinstance(record, DataRecord)
    assert len(hello.fields) == len(record.values) and record.boot == hello.boot
    import re

    for cmd in re.findall(r"`(\$C,[A-Z]+(?:,[0-9.]+)?\*[0-9A-F]{4})`", doc):
        assert parse_command(cmd.encode()).name in ("ID", "START", "STOP", "VOLT")
