"""Logger: --append reports what was lost while it was down and restarts; seq >= 2^32 refused; status without a tty."""
import io
import socket
import threading

import numpy as np
import pytest

from electrosense.validation.bench.log import read_bench_log
from electrosense.validation.bench.logger import Logger, rejected_path
from electrosense.validation.bench.logger.protocol import FrameError, encode_hello, encode_record, frame, parse_line

META = {"sensor": "angels-2", "emitter": 2, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": 0.0354}
FIELDS = ("t_s", "x_m", "y_m", "z_m", "yaw_rad", "U_V", "I1_A")


def _values(t_s, rng):
    return (f"{t_s:.3f}", f"{rng.uniform(-0.3, 0.3):.4f}", "0.0000", "0.0000", "0.000000", "1.000000",
            f"{rng.uniform(1e-4, 1e-3):.4e}")


class ScriptedDevice:
    """A TCP 'device' that sends the given raw lines once the host has spoken (its ``ID``), then stays open.

    It waits for the host's first command because opening a ``socket://`` port discards what arrived before.
    """

    def __init__(self, lines: list[bytes]):
        self.lines = lines
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        conn, _ = self.server.accept()
        with conn:
            heard = b""
            while b"\n" not in heard:
                chunk = conn.recv(256)
                if not chunk:
                    return
                heard += chunk
            conn.sendall(b"".join(self.lines))
            self.done.wait(10)

    def close(self):
        self.done.set()
        self.thread.join(5)
        self.server.close()


def _acquire(tmp_path, lines, samples, append=False, status=None, **kw):
    device = ScriptedDevice(lines)
    try:
        return Logger(device.url, tmp_path / "run.csv", META, samples=samples, append=append,
                      quiet=status is None, status=status, identify_timeout_s=5.0, seconds=10, **kw).run()
    finally:
        device.close()


def _records(boot, seqs, t0, rng):
    return [encode_record(boot, s, _values(t0 + 0.01 * k, rng)) for k, s in enumerate(seqs)]


@pytest.mark.parametrize("lost", [1, 37])
def test_append_after_a_crash_counts_the_records_lost_meanwhile(tmp_path, lost):
    rng = np.random.default_rng(lost)
    boot = int(rng.integers(0, 2**32))
    hello = encode_hello(boot, "test device", FIELDS)
    _acquire(tmp_path, [hello] + _records(boot, range(10), 0.0, rng), samples=10)
    start = 10 + lost
    summary = _acquire(tmp_path, [hello] + _records(boot, range(start, start + 5), 1.0, rng), samples=5, append=True)
    c = summary.counters
    assert c.records == 5 and c.gaps == 1 and c.missing == lost and c.missing_while_down == lost
    assert c.restarts == 0
    assert f"({lost} records missing, {lost} of them while the logger was down)" in summary.text()
    assert f"boot {boot} seq 9" in summary.text()
    log = read_bench_log(tmp_path / "run.csv")
    assert log.data.seq.tolist() == list(range(10)) + list(range(start, start + 5))
    assert "while the logger was down" in rejected_path(tmp_path / "run.csv").read_text()


def test_append_after_the_device_rebooted_is_a_restart(tmp_path):
    rng = np.random.default_rng(5)
    _acquire(tmp_path, [encode_hello(11, "dev", FIELDS)] + _records(11, range(8), 0.0, rng), samples=8)
    summary = _acquire(tmp_path, [encode_hello(12, "dev", FIELDS)] + _records(12, range(4), 0.0, rng),
                       samples=4, append=True)
    c = summary.counters
    assert c.restarts == 1 and c.gaps == 0 and c.records == 4
    assert "restarted meanwhile (now boot 12)" in summary.text()
    log = read_bench_log(tmp_path / "run.csv")
    assert np.all(np.diff(log.t_s) >= 0)  # the new boot's time is offset after the old one's


def test_append_without_a_hello_still_sees_the_restart(tmp_path):
    rng = np.random.default_rng(6)
    _acquire(tmp_path, _records(3, range(6), 0.0, rng), samples=6, fields=FIELDS)
    summary = _acquire(tmp_path, _records(4, range(3), 0.0, rng), samples=3, append=True, fields=FIELDS)
    assert summary.counters.restarts == 1 and summary.counters.missing == 0


def test_a_sequence_number_of_2_32_is_refused_and_the_next_record_kept(tmp_path):
    rng = np.random.default_rng(7)
    good = _records(9, range(3), 0.0, rng)
    bad = frame(",".join(["D", "9", str(2**32), *_values(0.5, rng)]))
    after = _records(9, [3], 0.6, rng)
    summary = _acquire(tmp_path, [encode_hello(9, "dev", FIELDS)] + good + [bad] + after, samples=4)
    c = summary.counters
    assert c.records == 4 and c.framing == 1 and c.duplicates == 0 and c.gaps == 0
    assert read_bench_log(tmp_path / "run.csv").data.seq.tolist() == [0, 1, 2, 3]
    assert "out of range" in rejected_path(tmp_path / "run.csv").read_text()


@pytest.mark.parametrize("field, text", [("seq", "4294967296"), ("seq", "99999999999999999999"),
                                         ("boot", "4294967296")])
def test_protocol_refuses_numbers_beyond_32_bits(field, text):
    parts = ["D", "1", "1", "0.0"]
    parts[1 if field == "boot" else 2] = text
    with pytest.raises(FrameError, match="out of range"):
        parse_line(frame(",".join(parts)))
    assert parse_line(frame("D,4294967295,4294967295,0.0"))[1].seq == 2**32 - 1


def test_status_without_a_terminal_is_whole_lines(tmp_path):
    rng = np.random.default_rng(8)
    out = io.StringIO()  # not a tty
    _acquire(tmp_path, [encode_hello(1, "dev", FIELDS)] + _records(1, range(20), 0.0, rng), samples=20,
             status=out, status_interval_s=0.0)
    text = out.getvalue()
    assert "\r" not in text and text.endswith("\n")
    assert all("records" in line for line in text.splitlines())
    assert "20 records" in text.splitlines()[-1]
