"""The PSM baseline corrected by the BEM on a few poses: a multi-fidelity baseline.

The PSM is fast but approximate: within a few centimetres of a wall it is off
the BEM by several percent (the images see the spheres, not the electrodes).
Diagnosed against the bare PSM, that approximation error looks like physics
(a moved wall, an object) and the diagnosis would blame the water for the
model. Here the BEM is run on a modest number of the logged poses, chosen
densely where the PSM's own tank effect changes fastest (near the walls), and
the ratio BEM/PSM of every entry of K is interpolated, pass by pass along the
path, to all samples::

    K_corrected = K_psm * exp(interp(log(K_bem / K_psm)))

What the interpolation cannot know is estimated by leaving each BEM pose out
in turn (the error of predicting it from its neighbours); that estimate,
interpolated likewise, is the model error of each sample, which the
diagnosis uses to weight the samples (s / sqrt(s^2 + e^2)).

Example
-------
>>> import numpy as np
>>> choose_bem_poses(np.array([0.0, 0.0, 0.1, 0.5, 0.5]), [np.arange(5)], 3).tolist()
[0, 3, 4]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.validation.diagnosis.forward import receiver_currents

__all__ = ["BEMCorrection", "choose_bem_poses", "bem_correction"]


def choose_bem_poses(tank_effect: np.ndarray, passes: list, n_poses: int) -> np.ndarray:
    """About ``n_poses`` sample indices, both ends of every pass, dense where ``tank_effect`` varies.

    The samples are spread evenly in the cumulative measure ``1/len + |d tank_effect| / total variation``
    along each pass (half uniform in the samples, half in the change of the tank's effect).
    """
    D = np.asarray(tank_effect, float)
    picks = []
    lengths = np.array([len(p) for p in passes], float)
    share = np.maximum(2, np.round(n_poses * lengths / lengths.sum()).astype(int))
    for idx, k in zip(passes, share):
        idx = np.asarray(idx)
        if len(idx) <= k:
            picks.append(idx)
            continue
        step = np.abs(np.diff(D[idx]))
        tv = step.sum()
        w = np.full(len(idx) - 1, 1.0 / (len(idx) - 1)) + (step / tv if tv > 0 else 0.0)
        s = np.concatenate([[0.0], np.cumsum(w)])
        targets = np.linspace(0.0, s[-1], k)
        j = np.unique(np.clip(np.searchsorted(s, targets), 0, len(idx) - 1))
        picks.append(idx[np.union1d(j, [0, len(idx) - 1])])
    return np.unique(np.concatenate(picks)).astype(int)


@dataclass
class BEMCorrection:
    """The interpolated BEM/PSM correction of a PSM baseline."""

    poses: np.ndarray  # (B,) sample indices where the BEM was run
    log_ratio: np.ndarray  # (P, n, n) interpolated log(K_bem / K_psm), zero on the diagonal
    error: np.ndarray  # (P, m) estimated error of the corrected receiver currents (relative)
    psm_vs_bem: np.ndarray  # (B, m) relative error of the bare PSM at the BEM poses
    leave_one_out: np.ndarray  # (B, m) relative error of the interpolated correction at the BEM poses

    def corrected(self, K_psm: np.ndarray) -> np.ndarray:
        """K_psm with the correction applied (zero row sums restored)."""
        K = K_psm * np.exp(self.log_ratio)
        n = K.shape[-1]
        off = K * (1 - np.eye(n))
        return off - np.eye(n) * off.sum(axis=-1, keepdims=True)


def _interp_along(values: np.ndarray, known: np.ndarray, passes: list, n_total: int) -> np.ndarray:
    """Linear interpolation in the sample order of each pass of ``values`` (B, ...) known at ``known``."""
    out = np.zeros((n_total,) + values.shape[1:])
    pos = {int(k): b for b, k in enumerate(known)}
    flat = values.reshape(len(known), -1)
    for idx in passes:
        idx = np.asarray(idx)
        here = [i for i, k in enumerate(idx) if int(k) in pos]
        if not here:  # a pass without any BEM pose: the nearest BEM pose in the sample order
            nearest = [pos[int(known[np.argmin(np.abs(known - k))])] for k in idx]
            out[idx] = values[nearest]
            continue
        x = np.asarray(here, float)
        y = flat[[pos[int(idx[i])] for i in here]]
        grid = np.arange(len(idx), dtype=float)
        out[idx] = np.stack([np.interp(grid, x, y[:, c]) for c in range(y.shape[1])], axis=1).reshape(
            (len(idx),) + values.shape[1:])
    return out


def bem_correction(obs, K_psm: np.ndarray, K_bem: np.ndarray, bem_poses: np.ndarray) -> BEMCorrection:
    """The correction from the BEM's K (B, n, n) at the samples ``bem_poses`` and the PSM's K (P, n, n) at all."""
    bem_poses = np.asarray(bem_poses, int)
    n = K_psm.shape[-1]
    off = ~np.eye(n, dtype=bool)
    ratio = np.where(off, K_bem / np.where(off, K_psm[bem_poses], 1.0), 1.0)
    if np.any(ratio[..., off] <= 0):
        raise ValueError("BEM and PSM disagree in the sign of a transfer conductance; no correction possible")
    L = np.log(ratio)
    passes = obs.pass_indices()
    log_ratio = _interp_along(L, bem_poses, passes, obs.n_poses)
    I = lambda K: receiver_currents(K, obs.emitter)  # noqa: E731
    I_bem = I(K_bem)
    psm_vs_bem = I(K_psm[bem_poses]) / I_bem - 1.0
    # leave each interior BEM pose out: how well do its neighbours predict it?
    loo = np.zeros_like(psm_vs_bem)
    for b in range(len(bem_poses)):
        keep = np.delete(np.arange(len(bem_poses)), b)
        if len(keep) == 0:
            continue
        guess = _interp_along(L[keep], bem_poses[keep], passes, obs.n_poses)[bem_poses[b]]
        Kc = BEMCorrection(bem_poses, guess[None], None, None, None).corrected(K_psm[bem_poses[b]][None])
        loo[b] = I(Kc)[0] / I_bem[b] - 1.0
    # the error of a sample: the leave-one-out error of its neighbours, interpolated (an upper estimate:
    # with the pose back in, the interpolation is denser); exact (zero) at the BEM poses themselves
    error = np.abs(_interp_along(np.abs(loo), bem_poses, passes, obs.n_poses))
    error[bem_poses] = 0.0
    return BEMCorrection(bem_poses, log_ratio, error, psm_vs_bem, loo)
