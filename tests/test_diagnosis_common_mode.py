"""The common-mode candidate: an instrument reading a complex fraction of the common-mode voltage, on a ring.

The medium is a resistor network (a ring of electrodes, each joined to every other with conductance falling
with the chord's length, and a ground electrode at the centre joined to all): any K would do for the fit,
this one has the ring's symmetry, so the common-mode voltage of an adjacent drive vanishes in the middle of
the far side, as in a tank.
"""
from __future__ import annotations

import numpy as np
import pytest

from electrosense.bem.protocol import adjacent_protocol, involves_drive
from electrosense.validation.comparison.transfer import drive_folds
from electrosense.validation.diagnosis.common_mode import common_mode_rows, fit_common_mode, instrument_reference
from electrosense.validation.diagnosis.transfer import common_mode_candidates


def ring_network_K(n: int, rng) -> np.ndarray:
    """(n+1, n+1) conductance matrix (S): n ring electrodes, electrode n+1 at the centre."""
    phi = 2 * np.pi * np.arange(n) / n
    xy = np.c_[np.cos(phi), np.sin(phi)]
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.eye(n)
    G = np.zeros((n + 1, n + 1))
    G[:n, :n] = 1.0 / d ** 2 - np.eye(n)
    G[:n, n] = G[n, :n] = rng.uniform(0.5, 2.0)
    return np.diag(G.sum(axis=1)) - G


def rows(n):
    d, m = adjacent_protocol(range(1, n + 1))
    keep = ~involves_drive(d, m)
    D, M = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return d[D[keep]], m[M[keep]]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_common_mode_fraction_is_found_with_its_uncertainty(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.choice([8, 16]))
    K = ring_network_K(n, rng)
    drive, measure = rows(n)
    ref = instrument_reference(n + 1, range(1, n + 1))
    assert ref == [n + 1]
    Z, Vcm, _ = common_mode_rows(K, drive, measure, ref)
    middle = (measure[:, 0] - drive[:, 0]) % n == n // 2      # the far side's middle pair of each drive
    assert np.all(np.abs(Vcm[middle]) < 1e-9 * np.abs(Z).max())
    c = complex(rng.uniform(-3e-3, 3e-3), rng.uniform(1e-2, 3e-2))
    noise = 2e-4
    Zd = 7.0 * np.abs(Z + c * Vcm) * (1 + noise * rng.standard_normal(len(Z)))
    folds = drive_folds(drive)[2]
    sc, res, p = fit_common_mode(Zd, Z, Vcm, folds)
    assert sc["heldout_rms_rel"] < 1.5 * noise and sc["n_parameters"] == 3
    assert abs(p["c_in_phase"] - c.real) < 4 * p["c_in_phase_se"] + 1e-6
    assert abs(p["c_quadrature"] - c.imag) < 4 * p["c_quadrature_se"] + 1e-6
    assert p["c_quadrature_se"] < 0.3 * c.imag
    # the diagnosis's candidates: common_mode explains it, far better than the stated model (scale alone)
    cands, resid, designs = common_mode_candidates(K, drive, measure, Zd, folds, list(range(1, n + 1)))
    assert cands["common_mode"]["reference_electrodes"] == [n + 1]
    assert cands["common_mode"]["heldout_rms_rel"] < 1.5 * noise
    scale_only = np.median(Zd / np.abs(Z))
    assert np.sqrt(np.mean((scale_only * np.abs(Z) / Zd - 1) ** 2)) > 5 * cands["common_mode"]["heldout_rms_rel"]
    assert resid["common_mode"].shape == Z.shape and set(designs) == set(cands)


def test_without_a_common_mode_the_fit_finds_none():
    rng = np.random.default_rng(3)
    n = 16
    K = ring_network_K(n, rng)
    drive, measure = rows(n)
    Z, Vcm, _ = common_mode_rows(K, drive, measure, [n + 1])
    Zd = 2.0 * np.abs(Z) * (1 + 1e-3 * rng.standard_normal(len(Z)))
    sc, _, p = fit_common_mode(Zd, Z, Vcm, drive_folds(drive)[2])
    assert sc["heldout_rms_rel"] < 1.2e-3
    assert abs(p["c_in_phase"]) < 4 * p["c_in_phase_se"]
    # |c''| enters squared, so near zero it is poorly determined: what is found moves no measurement beyond noise
    assert np.max(np.hypot(1, p["c_quadrature"] * Vcm / Z) - 1) < 3e-3
