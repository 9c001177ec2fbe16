"""The logger end to end, against the virtual bench, through a real pseudo-terminal (and a socket):
every fault kind, every good record exactly once, a kill -9 in the middle of a run."""
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from electrosense.bem.conductance import ConductanceMatrix
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log import read_bench_log
from electrosense.validation.bench.logger import Logger, rejected_path
from electrosense.validation.bench.virtual import (
    BenchDevice,
    FaultPlan,
    PtyTransport,
    SocketTransport,
    VirtualBench,
    wall_to_wall,
)

META = {"sensor": "angels-4", "emitter": 4, "tank_m": [1.0, 1.0, 1.0], "sigma_S_per_m": 0.0354}


def standin_simulate(model, sensor, poses, tank, sigma_S_per_m, objects=(), psm_model=None,
                     contact_impedance_ohm_m2=None, **options):
    """A trivial stand-in for the models: a valid K (symmetric, zero row sums) varying with x."""
    n = sensor.n_electrodes
    g = sigma_S_per_m * 0.02 * (1.0 + np.asarray(poses)[:, 0] ** 2)
    off = -1.0 / (1.0 + np.abs(np.subtract.outer(np.arange(n), np.arange(n))))
    np.fill_diagonal(off, 0.0)
    K = g[:, None, None] * off
    K[:, np.arange(n), np.arange(n)] = -K.sum(axis=2)
    return ConductanceMatrix(K, sensor.emitter, sigma_S_per_m)


def simulated_run(n=240, rate=240.0, seed=1):
    bench = VirtualBench(preset("angels-4"), Tank((1.0, 1.0, 1.0)), 0.0354, simulate=standin_simulate, seed=seed)
    return bench.run(wall_to_wall(n=n), rate_hz=rate)


def serve_in_thread(device, linger_s=30.0):
    stop = threading.Event()
    thread = threading.Thread(target=device.serve, kwargs={"stop": stop, "linger_s": linger_s}, daemon=True)
    thread.start()
    return thread, stop


def stop_when_done(device, thread, logger, run_length, timeout_s=15.0):
    """Stop the logger once the device has produced everything and the logger has taken every sent record."""
    t0 = time.monotonic()
    while sum(device.report.fates.values()) < run_length and time.monotonic() - t0 < timeout_s:
        time.sleep(0.02)
    while logger.counters.records < device.report.fates["sent"] and time.monotonic() - t0 < timeout_s:
        time.sleep(0.02)
    logger.stop.set()


def expected_missing(truth):
    """Records the logger can know are missing: not sent intact, between two received ones of the same boot."""
    d = truth.data
    total = 0
    for _, rows in d.groupby("boot"):
        got = rows.seq[rows.fate == "sent"]
        if len(got):
            lost = rows[(rows.fate != "sent") & (rows.seq > got.min()) & (rows.seq < got.max())]
            total += len(lost)
    return total


@pytest.mark.parametrize("kind", ["pty", "socket"])
def test_every_fault_kind_every_good_record_exactly_once(tmp_path, kind):
    run = simulated_run(n=360)  # 1.5 s: the line comes back with time to spare for the faults after it
    transport = PtyTransport(tmp_path / "bench") if kind == "pty" else SocketTransport()
    plan = FaultPlan.parse("corrupt=3,drop=3,garbage=4,disconnect=1,restart=1", disconnect_s=0.2)
    device = BenchDevice(run, transport, rate_hz=240.0, faults=plan, seed=7, truth_path=tmp_path / "truth.csv",
                         truth_meta=META)
    thread, stop_device = serve_in_thread(device)
    logger = Logger(transport.path, tmp_path / "run.csv", META, quiet=True, reconnect_interval_s=0.05)
    watcher = threading.Thread(target=stop_when_done, args=(device, thread, logger, len(run)), daemon=True)
    watcher.start()
    try:
        summary = logger.run()
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    assert dict(device.report.faults) == plan.counts  # every fault really happened
    log, truth = read_bench_log(tmp_path / "run.csv"), read_bench_log(tmp_path / "truth.csv")
    assert log.warnings == [] and "SIMULAT" in log.meta["device"] and "SIMULATED" in truth.meta["source"]
    sent = truth.data[truth.data.fate == "sent"]
    got = list(zip(log.data.boot, log.data.seq))
    assert len(got) == len(set(got)) == len(sent)  # exactly once
    assert set(got) == set(zip(sent.boot, sent.seq))
    # the values landed as the device sent them
    merged = log.data.merge(sent, on=["boot", "seq"], suffixes=("", "_truth"))
    for c in ("x_m", "y_m", "I1_A", "I2_A", "I3_A", "U_V", "temp_C", "pass"):
        np.testing.assert_array_equal(merged[c], merged[c + "_truth"])
    assert np.all(np.diff(log.t_s) >= 0)
    c = summary.counters
    assert c.corrupt == (truth.data.fate == "corrupt").sum() == 3
    assert c.garbage == (sent.noise == "prefix").sum()
    assert c.framing == (truth.data.noise == "line").sum()
    assert c.garbage + c.framing == 4
    assert c.restarts == 1 and c.reconnects == 1 and c.duplicates == 0 and c.refused == 0
    assert c.missing == expected_missing(truth)
    side = rejected_path(tmp_path / "run.csv").read_text()
    assert side.count("\tchecksum: CRC") == 3 and "device restarted" in side and "lost; waiting" in side


def test_refuses_to_overwrite_and_appends_on_request(tmp_path):
    run = simulated_run(n=60)
    transport = PtyTransport(tmp_path / "bench")
    device = BenchDevice(run, transport, rate_hz=240.0, seed=3)
    thread, stop_device = serve_in_thread(device)
    try:
        Logger(transport.path, tmp_path / "run.csv", META, quiet=True, samples=20).run()
        with pytest.raises(FileExistsError, match="refusing to overwrite"):
            Logger(transport.path, tmp_path / "run.csv", META, quiet=True, samples=10)
        Logger(transport.path, tmp_path / "run.csv", META, quiet=True, samples=10, append=True, voltage_V=2.0).run()
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    log = read_bench_log(tmp_path / "run.csv")
    assert len(log) == 30 and len(set(zip(log.data.boot, log.data.seq))) == 30
    assert np.all(np.diff(log.t_s) >= 0)
    # VOLT: the device doubled its voltage and the currents followed (linear in U)
    np.testing.assert_array_equal(log.U_V, [1.0] * 20 + [2.0] * 10)
    R = log.resistance_ohm
    np.testing.assert_allclose(R[20:], np.broadcast_to(R[19], (10, 3)), rtol=0.02)


def test_kill_minus_nine_leaves_a_readable_log(tmp_path):
    run = simulated_run(n=4000, rate=400.0)
    transport = PtyTransport(tmp_path / "bench")
    device = BenchDevice(run, transport, rate_hz=400.0, seed=5, truth_path=tmp_path / "truth.csv", truth_meta=META)
    thread, stop_device = serve_in_thread(device)
    log_path = tmp_path / "run.csv"
    meta = "sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354"
    cmd = [sys.executable, "-c", "from electrosense.validation.cli import main; main()", "acquire", "--port", transport.path,
           "-o", str(log_path), "--meta", meta, "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60:
            if log_path.exists() and log_path.read_bytes().count(b"\n") > 200:
                break
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(5)
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    assert proc.returncode == -signal.SIGKILL
    log = read_bench_log(log_path)  # no refusal: at most one partial last line, reported
    assert len(log.warnings) <= 1 and len(log) > 150
    truth = read_bench_log(tmp_path / "truth.csv")
    sent = truth.data.set_index(["boot", "seq"])
    rows = sent.loc[list(zip(log.data.boot, log.data.seq))]
    np.testing.assert_array_equal(rows["I1_A"].to_numpy(), log.data["I1_A"].to_numpy())
    assert np.all(np.diff(log.data.seq) == 1)  # nothing lost before the kill


def test_ctrl_c_on_the_command_stops_cleanly_with_a_summary(tmp_path):
    run = simulated_run(n=4000, rate=400.0)
    transport = SocketTransport()
    device = BenchDevice(run, transport, rate_hz=400.0, seed=5)
    thread, stop_device = serve_in_thread(device)
    log_path = tmp_path / "run.csv"
    cmd = [sys.executable, "-c", "from electrosense.validation.cli import main; main()", "acquire", "--port", transport.url,
           "-o", str(log_path), "--meta", "sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and not (log_path.exists() and log_path.read_bytes().count(b"\n") > 50):
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    assert proc.returncode == 0, err
    log = read_bench_log(log_path)
    assert log.warnings == [] and f"{len(log)} records written" in err and "stopped by interrupt (Ctrl-C)" in err
    # the live status was shown, as whole lines (stderr is a pipe here, not a terminal)
    assert "/s  rejected " in err and "\r" not in err


def test_a_streaming_device_with_fields_given_and_a_device_that_does_not_fit_the_meta(tmp_path):
    run = simulated_run(n=120, rate=240.0)
    transport = SocketTransport()
    thread, stop_device = serve_in_thread(BenchDevice(run, transport, rate_hz=240.0, seed=3))
    try:
        with pytest.raises(ValueError, match=r"do not fit the log's meta \(sensor angels-2, emitter 2\): "
                                             r"receiver column count 3"):
            Logger(transport.url, tmp_path / "wrong.csv", dict(META, sensor="angels-2", emitter=2), quiet=True,
                   identify_timeout_s=5.0, seconds=5.0).run()
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    assert not (tmp_path / "wrong.csv").exists()

    transport = SocketTransport()
    device = BenchDevice(run, transport, rate_hz=240.0, seed=3, autostart=True, truth_path=tmp_path / "truth.csv",
                         truth_meta=META)
    thread, stop_device = serve_in_thread(device, linger_s=5.0)
    logger = Logger(transport.url, tmp_path / "run.csv", META, quiet=True, fields=run.columns, start_device=False)
    watcher = threading.Thread(target=stop_when_done, args=(device, thread, logger, len(run)), daemon=True)
    watcher.start()
    try:
        logger.run()
    finally:
        stop_device.set()
        thread.join(5)
        transport.close()
    log, truth = read_bench_log(tmp_path / "run.csv"), read_bench_log(tmp_path / "truth.csv")
    # the device streams from power-up: what it wrote before the logger's ID may have been flushed by the
    # port's opening ("unheard"); everything written after it must be in the log, and nothing else
    fate = truth.data.fate
    sent = truth.data[fate == "sent"]
    maybe = truth.data[fate == "unheard"]
    logged = set(zip(log.data.boot, log.data.seq))
    assert len(sent) > 0 and set(zip(sent.boot, sent.seq)) <= logged
    assert logged <= set(zip(sent.boot, sent.seq)) | set(zip(maybe.boot, maybe.seq))
    assert set(fate) <= {"sent", "unheard", "unsent"}
    assert log.meta["device"].startswith("unknown (fields given by the user)")


def test_an_autostart_device_marks_what_it_wrote_before_the_host_spoke_as_unheard(tmp_path):
    """Opening a port flushes what waits in it (pyserial does, for a socket too), so a record an
    autostart device wrote before the host said anything may or may not reach the host: the truth
    file says "unheard", never "sent". A raw client that keeps everything sees all of them."""
    import socket

    from electrosense.validation.bench.logger.protocol import DataRecord, encode_command, parse_line

    run = simulated_run(n=60, rate=200.0)
    transport = SocketTransport()
    device = BenchDevice(run, transport, rate_hz=200.0, seed=5, autostart=True, truth_path=tmp_path / "truth.csv",
                         truth_meta=META)
    thread, stop_device = serve_in_thread(device, linger_s=1.0)
    received = b""
    with socket.create_connection((transport.host, transport.port)) as client:
        client.settimeout(0.05)
        t0 = time.monotonic()
        spoke = False
        while thread.is_alive() and time.monotonic() - t0 < 10.0:
            if not spoke and received.count(b"$D") >= 5:  # silent until five records came, then ID
                client.sendall(encode_command("ID"))
                spoke = True
            try:
                received += client.recv(65536)
            except socket.timeout:
                pass
            if sum(device.report.fates.values()) == len(run):
                break
        time.sleep(0.1)
        try:
            received += client.recv(65536)
        except socket.timeout:
            pass
    stop_device.set()
    thread.join(5)
    transport.close()
    truth = read_bench_log(tmp_path / "truth.csv").data
    fates = list(truth.fate)
    assert spoke and set(fates) <= {"unsent", "unheard", "sent"}
    assert fates.count("unheard") >= 5 and fates.count("sent") > 0
    # the order on the line: nobody connected, connected but silent, heard
    order = {"unsent": 0, "unheard": 1, "sent": 2}
    assert [order[f] for f in fates] == sorted(order[f] for f in fates)
    got = {(m.boot, m.seq) for m in (parse_line(line + b"\n")[1] for line in received.split(b"\n") if b"$D" in line)
           if isinstance(m, DataRecord)}
    written = truth[truth.fate != "unsent"]
    assert got == set(zip(written.boot, written.seq))


def test_acquire_names_a_sensor_file_given_by_its_absolute_path_as_the_log_can_read_it(tmp_path):
    """`esense acquire --meta sensor=/abs/probe.json` (what `esense bench-sim --pty` prints for a sensor file):
    the log names the file relative to its folder where it lies there, else a copy beside it."""
    import dataclasses

    from click.testing import CliRunner

    from electrosense.meshes.sensor import preset, save_sensor
    from electrosense.validation.cli import main

    probe = dataclasses.replace(preset("angels-4"), name="my-probe")
    save_sensor(probe, tmp_path / "probe.json")
    (tmp_path / "elsewhere").mkdir()
    for out, named in ((tmp_path / "run.csv", "probe.json"), (tmp_path / "elsewhere" / "run.csv", "run.sensor.json")):
        transport = SocketTransport()
        thread, stop_device = serve_in_thread(BenchDevice(simulated_run(n=40, rate=400.0), transport, rate_hz=400.0))
        try:
            run = CliRunner().invoke(main, ["acquire", "--port", transport.url, "-o", str(out), "--quiet", "--samples",
                                            "10", "--meta", f"sensor={tmp_path / 'probe.json'},emitter=4,tank=1,1,1,"
                                                            "sigma=0.0354"])
        finally:
            stop_device.set()
            thread.join(5)
            transport.close()
        assert run.exit_code == 0, run.output
        log = read_bench_log(out)
        assert log.meta["sensor"] == named and log.sensor == probe and len(log) == 10
    taken = tmp_path / "elsewhere" / "taken.csv"
    taken.write_text("a user's file\n")
    run = CliRunner().invoke(main, ["acquire", "--port", "loop://", "-o", str(taken), "--quiet", "--meta",
                                    f"sensor={tmp_path / 'probe.json'},emitter=4,tank=1,1,1,sigma=0.0354"])
    assert run.exit_code == 1 and "refusing to overwrite" in run.output
    assert taken.read_text() == "a user's file\n" and not (tmp_path / "elsewhere" / "taken.sensor.json").exists()
