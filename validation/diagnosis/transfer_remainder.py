"""Where the rest of a transfer log's gap lies: the tank's symmetric shape, shared scatter, broken reciprocity.

The residuals ``r`` (model / measured - 1, each row held out) that the
chosen candidate leaves are split into parts whose squares add up:

* ``by_ring_offset``: the mean of ``r`` over each ring offset (measurement
  pair's distance from the drive pair). A tank that is symmetric about its
  axis, with equal electrodes equally spaced, gives one value per offset:
  this part is what a smooth geometric effect (depth, radius, ring height,
  electrode size) could still remove;
* ``shared_by_reciprocal_pairs``: what is left, averaged over each
  reciprocal pair (drive and measurement swapped), beyond what noise puts
  there. Reciprocity holds for any linear passive medium, so this part is a
  property of the scene or of single electrodes and pairs (positions,
  shapes, shunts between leads), not of the instrument's noise;
* ``noise``: half the difference of each reciprocal pair (what breaks
  reciprocity: the instrument), counted twice: errors independent between
  the two measurements of a pair put as much into their mean as into their
  difference. No model of the water can remove it;
* ``unpaired``: rows without a reciprocal partner.

``shares`` are fractions of the total sum of squares; ``largest`` lists the
rows that hold most of it, with their reciprocal partner's residual (a large
pair that agrees is a property of the scene, one that does not is the
instrument's). On a ring with an even number of electrodes,
``by_pair_parity`` gives the mean of ``r`` (less its offset mean) over the
four classes of (drive pair, measurement pair) parity along the ring: a
system wired or multiplexed by parity shows there, and no tank geometry or
product of per-pair gains makes one class stand apart from the other three.
Drive-parity folds (even drives fitted, odd ones scored) never fit the
odd-odd class, so no candidate can learn such an effect on them.

Example
-------
A symmetric error of 2 % at offset 2 and 1 % of antisymmetric noise:

>>> drive = np.array([[1, 2], [3, 4], [1, 2], [5, 6]]); measure = np.array([[3, 4], [1, 2], [5, 6], [1, 2]])
>>> offsets = np.array([2, 2, 4, 4])
>>> out = where_the_rest_lies(drive, measure, offsets, np.array([0.03, 0.01, 0.0, 0.0]))
>>> {k: round(v, 3) for k, v in out["shares"].items()}
{'by_ring_offset': 0.8, 'shared_by_reciprocal_pairs': 0.0, 'noise': 0.2, 'unpaired': 0.0}
"""
from __future__ import annotations

import numpy as np

from electrosense.validation.comparison.transfer import pair_parity_classes, reciprocal_pairs

__all__ = ["where_the_rest_lies"]

_MEANING = {
    "by_ring_offset": "the tank's symmetric shape (mean by ring offset): a smooth geometric effect could remove it",
    "shared_by_reciprocal_pairs": "scatter that reciprocal pairs share beyond noise: single electrodes or pairs "
                                  "(positions, shapes, shunts between leads), not the instrument's noise",
    "noise": "what breaks reciprocity, twice (as much again hides in the pairs' mean): the instrument, beyond any "
             "model of the water",
    "unpaired": "rows without a reciprocal partner",
}


def where_the_rest_lies(drive, measure, offsets, residual, n_largest: int = 4, ring=()) -> dict:
    """Split the residuals ``residual`` (R,) of a transfer log's rows into the parts of the module docstring.

    Parameters
    ----------
    drive, measure : (R, 2) electrode pairs (1-based) of each row.
    offsets : (R,) ring offset of each row, or None (no ring: no symmetric part).
    residual : (R,) model / measured - 1, each row held out.
    n_largest : how many of the largest rows to list.
    ring : the ring's electrodes in order (for ``by_pair_parity``).

    Returns
    -------
    dict with ``rms_rel`` (of all rows), ``shares`` (fractions of the sum of
    squares, adding up to 1), ``rms_rel_by_part``, ``meaning`` (each part in
    words), ``largest`` (rows, their partner's residual, their share) and
    ``text`` (one sentence).
    """
    r = np.asarray(residual, float)
    total = float(np.sum(r ** 2)) or 1.0
    sym = np.zeros_like(r)
    if offsets is not None:
        off = np.asarray(offsets)
        for o in np.unique(off):
            sym[off == o] = r[off == o].mean()
    s = r - sym
    i, j = reciprocal_pairs(np.asarray(drive), np.asarray(measure))
    paired = np.zeros(len(r), bool)
    paired[i] = paired[j] = True
    shared = 0.5 * (s[i] + s[j])
    broken = 0.5 * (s[i] - s[j])
    ss_shared, ss_broken = float(2 * np.sum(shared ** 2)), float(2 * np.sum(broken ** 2))
    ss = {"by_ring_offset": float(np.sum(sym ** 2)), "shared_by_reciprocal_pairs": max(ss_shared - ss_broken, 0.0),
          "noise": min(2 * ss_broken, ss_shared + ss_broken), "unpaired": float(np.sum(s[~paired] ** 2))}
    partner = np.full(len(r), np.nan)
    partner[i], partner[j] = r[j], r[i]
    top = np.argsort(-np.abs(r))[:n_largest]
    largest = [{"drive": np.asarray(drive)[k].tolist(), "measure": np.asarray(measure)[k].tolist(),
                "rel": float(r[k]), "reciprocal_partner_rel": None if np.isnan(partner[k]) else float(partner[k]),
                "share": float(r[k] ** 2 / total)} for k in top]
    shares = {k: v / total for k, v in ss.items()}
    n = len(r)
    parity = None
    classes = None if len(ring) % 2 else pair_parity_classes(drive, measure, ring)     # an even ring's classes
    if classes is not None:
        parity = {f"{'eo'[c // 2]}{'eo'[c % 2]}": float(s[classes == c].mean()) for c in range(4)
                  if np.any(classes == c)}
    main = max(shares, key=shares.get)
    text = (f"of the held-out gap (RMS {np.sqrt(total / n):.4f}), " +
            ", ".join(f"{100 * v:.0f} % {k.replace('_', ' ')}" for k, v in shares.items() if v > 0.005) +
            f"; most of it: {_MEANING[main]}; the {n_largest} largest rows hold "
            f"{100 * sum(x['share'] for x in largest):.0f} %")
    if parity:
        text += ("; mean by (drive, measurement) pair parity, offset mean removed: " +
                 ", ".join(f"{k} {100 * v:+.1f} %" for k, v in parity.items()))
    return {"rms_rel": float(np.sqrt(total / n)), "shares": shares,
            "rms_rel_by_part": {k: float(np.sqrt(v / n)) for k, v in ss.items()},
            "meaning": _MEANING, "largest": largest, "by_pair_parity": parity, "text": text}
