"""Serial acquisition: the bench's line protocol and the logger that writes bench logs from it.

* :mod:`.protocol`: framed ASCII lines with a sequence number and a CRC-16
  (see docs/serial-protocol.md);
* :mod:`.logger`: :class:`Logger`, the acquisition loop (any pyserial URL);
* :mod:`.meta_option`: the ``--meta key=value,...`` text of ``esense acquire``.
"""
from electrosense.validation.bench.logger.logger import AcquisitionCounters, AcquisitionSummary, Logger, rejected_path
from electrosense.validation.bench.logger.meta_option import parse_meta_option
from electrosense.validation.bench.logger.protocol import (
    Ack,
    Command,
    DataRecord,
    FrameError,
    Hello,
    SequenceTracker,
    crc16,
    encode_command,
    encode_hello,
    encode_record,
    parse_command,
    parse_line,
)

__all__ = [
    "Logger", "AcquisitionCounters", "AcquisitionSummary", "rejected_path", "parse_meta_option", "crc16",
    "encode_record", "encode_hello", "encode_command", "parse_line", "parse_command", "DataRecord", "Hello", "Ack",
    "Command", "FrameError", "SequenceTracker",
]
