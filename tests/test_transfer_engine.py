"""The pose diagnosis's engine on transfer logs: random rings, noise alone and injected instrument effects."""
import numpy as np
import pytest

from electrosense.validation.diagnosis.transfer import channel_blocks, engine_blocks, pair_parity_blocks
from electrosense.validation.diagnosis.transfer_engine import TransferProblem, diagnose_rows


def _ring_log(rng, n: int):
    """Adjacent drives and measurements on a ring of ``n`` electrodes (those touching a drive electrode left out),
    with a smooth positive model magnitude of each row."""
    drive, measure = [], []
    for k in range(n):
        for m in range(n):
            d, q = {k, (k + 1) % n}, {m, (m + 1) % n}
            if d & q:
                continue
            drive.append([k + 1, (k + 1) % n + 1])
            measure.append([m + 1, (m + 1) % n + 1])
    drive, measure = np.array(drive), np.array(measure)
    offset = (measure[:, 0] - drive[:, 0]) % n
    Zm = (1.0 + 3.0 / offset**1.5) * rng.uniform(0.9, 1.1)        # larger next to the drive, as a real ring
    return drive, measure, Zm


def _problem(rng, n, Zd_of, noise):
    drive, measure, Zm = _ring_log(rng, n)
    Zd = Zd_of(Zm, drive, measure) * 7.3 * (1 + noise * rng.standard_normal(len(Zm)))      # arbitrary units
    blocks = {"scale": [Zm], **channel_blocks(Zm, measure), **pair_parity_blocks(Zm, drive, measure, range(1, n + 1))}
    index = np.unique(drive, axis=0, return_inverse=True)[1].ravel()
    return TransferProblem.scaled(index, Zm, Zd, np.ones(len(Zm)),
                                  engine_blocks(blocks, Zm, measure, None, None, [], range(1, n + 1)))


def test_noise_alone_is_answered_none_on_random_rings():
    """Eight random rings (8-16 electrodes), 0.2 % noise: the detection test's false-alarm rate is 1 %."""
    rng = np.random.default_rng(3)
    verdicts = []
    for _ in range(8):
        n = int(rng.integers(8, 17))
        out, _, _ = diagnose_rows(_problem(rng, n, lambda Zm, d, m: Zm, 2e-3), noise=2e-3)
        verdicts.append(out["verdict"])
        assert out["gap_before"] < 1.5 * 2e-3 and out["detection"]["alpha"] == 0.01
    assert verdicts.count("none") >= 7, verdicts


@pytest.mark.parametrize("seed", [0, 1])
def test_injected_channel_gains_and_a_multiplexer_class_are_named(seed):
    """Gains per measurement channel (2 % RMS) or one parity class 4 % low, at 0.2 % noise: named, the held-out gap
    brought to the noise, each parameter within four standard errors."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 17))
    g = 0.02 * rng.standard_normal(n)
    out, _, _ = diagnose_rows(_problem(rng, n, lambda Zm, d, m: Zm * (1 + g[m[:, 0] - 1]), 2e-3), noise=2e-3)
    assert out["chosen"] == "channel_gains" and out["verdict"] == "explained", out["steps"]
    assert out["gap_after"] < 1.5 * 2e-3
    found = np.array(list(out["parameters"]["channel_gains"].values()))
    se = np.array(list(out["standard_errors"]["channel_gains"].values()))
    truth = g - g.mean()                                     # the mean gain is the scale's (the gauge)
    assert np.all(np.abs(found - truth) < 4 * se + 1e-3)

    odd_odd = lambda Zm, d, m: Zm * np.where((d[:, 0] % 2 == 0) & (m[:, 0] % 2 == 0), 0.96, 1.0)   # noqa: E731
    out, _, _ = diagnose_rows(_problem(rng, n, odd_odd, 2e-3), noise=2e-3)
    assert out["chosen"] == "pair_parity_gains", out["steps"]
    p = out["parameters"]["pair_parity_gains"]
    assert abs(p["gain_odd-odd"] + 0.04) < 0.005 and abs(p["gain_even-odd"]) < 0.005


@pytest.mark.parametrize("seed", [0, 1])
def test_a_multiplexer_class_offset_is_named_and_not_taken_for_a_class_gain(seed):
    """A fixed voltage added per parity class (crosstalk of a multiplexer's groups; relative to the reading largest
    where the transfer impedance is smallest), at 0.2 % noise: ``pair_parity_offsets`` is named, each class's offset
    within four standard errors; a class gain cannot stand in for it."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 17))
    o = rng.uniform(-0.03, 0.03, 4)                  # per class, in units of the far side's model magnitude
    add = lambda Zm, d, m: Zm + o[2 * ((d[:, 0] - 1) % 2) + (m[:, 0] - 1) % 2]     # noqa: E731
    out, _, _ = diagnose_rows(_problem(rng, n, add, 2e-3), noise=2e-3)
    assert out["chosen"] == "pair_parity_offsets" and out["verdict"] == "explained", out["steps"]
    assert out["gap_after"] < 1.5 * 2e-3
    found = np.array(list(out["parameters"]["pair_parity_offsets"].values()))
    se = np.array(list(out["standard_errors"]["pair_parity_offsets"].values()))
    assert np.all(np.abs(found - o) < 4 * se + 1e-3), (found, o, se)
