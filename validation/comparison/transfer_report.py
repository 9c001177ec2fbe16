"""Figures and the report of a transfer log's comparison with the BEM (and of its diagnosis, when run).

* ``empty_tank.png``: measured against BEM x fitted scale (fitted and held-out
  drives), and the reciprocity histogram (the measurement's own floor);
* ``difference_signals.png``: each set-up's measured and simulated signal;
* ``geometry.png``: model / measured - 1 by ring offset for the stated tank
  and the shape candidates, and the ring radius the empty tank and each ball
  want (:func:`electrosense.validation.diagnosis.transfer.one_geometry`);
* ``candidates.png``: each candidate's gap on held-out drives and on the
  object set-ups (fitted on the empty tank), against the floor;
* ``remainder.png``: where the gap lies before any effect and after the
  chosen one (:func:`electrosense.validation.diagnosis.transfer_remainder.where_the_rest_lies`):
  the shares of its parts and the mean by pair parity class;
* ``report.md``: the numbers beside the goals, and the figures.

Figures use the shared look of :mod:`electrosense.validation.report.style` (a PDF beside
each PNG).

Example
-------
>>> import tempfile, pathlib
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> Zd = np.array([1.0, 2.0, 3.0, 4.0])
>>> empty_tank_figure(folder, Zd, 1.01 * Zd, np.array([True, False, True, False]), np.array([0.01, -0.02])).name
'empty_tank.png'
>>> m = {"noise_floor": {"per_measurement_rms_rel": 0.012}, "empty_heldout_rms_rel": 0.1, "object_rms_rel": {}}
>>> print(next(line for line in summary_text(m).splitlines() if line.startswith("goals")))
goals: empty_heldout_rms_rel <= 0.024 (2x the file's floor per measurement); each object_rms_rel <= 0.15; diagnosis shrink >= 0.5
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from electrosense.validation.comparison.study_mesh import BEM_ERROR_OVER_NOISE
from electrosense.validation.report.style import new_figure, save

__all__ = [
    "EMPTY_FLOOR_FACTOR",
    "OBJECT_GOAL_REL",
    "SHRINK_GOAL",
    "empty_tank_goal",
    "goals",
    "goals_table",
    "goals_text",
    "difference_signals_figure",
    "empty_tank_figure",
    "candidates_figure",
    "geometry_figure",
    "remainder_figure",
    "report_markdown",
    "summary_text",
    "write_transfer_report",
]

#: the empty tank's goal on held-out drives, in units of the file's own per-measurement reciprocity floor (issue 24:
#: what the instrument itself cannot repeat bounds what a model of the tank can be asked for)
EMPTY_FLOOR_FACTOR = 2.0
OBJECT_GOAL_REL = 0.15   # each ball set-up's signal, RMS relative, on set-ups not used in a fit
SHRINK_GOAL = 0.5        # the share of the held-out gap the diagnosis removes


def empty_tank_goal(m: dict) -> float | None:
    """The empty tank's goal for the metrics ``m``: EMPTY_FLOOR_FACTOR x its per-measurement floor (None unknown)."""
    floor = m.get("noise_floor", {}).get("per_measurement_rms_rel")
    return None if floor is None or not np.isfinite(floor) else EMPTY_FLOOR_FACTOR * float(floor)


def goals(m: dict) -> dict:
    """The goals for the metrics ``m`` (written into metrics.json beside the figures they judge)."""
    return {"empty_heldout_rms_rel": empty_tank_goal(m), "empty_heldout_floor_factor": EMPTY_FLOOR_FACTOR,
            "object_rms_rel": OBJECT_GOAL_REL, "diagnosis_shrink": SHRINK_GOAL}


def goals_text(m: dict) -> str:
    """The goals printed beside the figures, the empty tank's from the file's own floor."""
    g = empty_tank_goal(m)
    empty = (f"empty_heldout_rms_rel <= {g:.3f} ({EMPTY_FLOOR_FACTOR:g}x the file's floor per measurement)"
             if g is not None else f"empty_heldout_rms_rel <= {EMPTY_FLOOR_FACTOR:g}x the floor per measurement")
    return f"goals: {empty}; each object_rms_rel <= {OBJECT_GOAL_REL:g}; diagnosis shrink >= {SHRINK_GOAL:g}"


def goals_table(m: dict) -> str:
    """Each goal beside what the stated scene, the diagnosis and each scene fit reach (markdown table; a fit scores
    a ball set-up it was fitted on, marked "fitted", and the others held out), and the least misfit any scene with
    the set-up's stated symmetry leaves (:mod:`~electrosense.validation.comparison.symmetry`): a goal below it is out
    of reach for every such scene.

    >>> print(goals_table({"noise_floor": {"per_measurement_rms_rel": 0.01}, "empty_heldout_rms_rel": 0.1,
    ...                    "object_rms_rel": {"Avg1": 0.2}, "diagnosis": {"gap_before": 0.1, "gap_after": 0.02}}))
    | goal | stated scene | diagnosis | met | least any scene with the stated symmetry leaves |
    |---|---|---|---|---|
    | empty tank, held-out drives <= 0.020 | 0.100 | 0.020 | yes |  |
    | Avg1 signal <= 0.15 | 0.200 |  | no |  |
    | the gap shrunk >= 50 % |  | 80 % | yes |  |
    """
    g = empty_tank_goal(m)
    d = m.get("diagnosis", {})
    fits = m.get("scene_fit", {}).get("fits", {})
    cols = ["stated scene"] + (["diagnosis"] if "gap_after" in d else []) + [f"scene fit, {k}" for k in fits]

    def row(label, values, goal, fitted=(), larger_is_better=False):
        judged = [v for c, v in values.items() if c not in fitted and v is not None and np.isfinite(v)]
        met = None
        if judged and goal is not None:
            met = max(judged) >= goal if larger_is_better else min(judged) <= goal
        cells = ["" if values.get(c) is None else (f"{100 * values[c]:.0f} %" if larger_is_better
                                                    else f"{values[c]:.3f}") + (" (fitted)" if c in fitted else "")
                 for c in cols]
        return f"| {label} | " + " | ".join(cells) + f" | {'' if met is None else 'yes' if met else 'no'} |"

    lines = ["| goal | " + " | ".join(cols) + " | met | least any scene with the stated symmetry leaves |",
             "|---|" + "---|" * (len(cols) + 2)]

    def floor(f):
        return "" if f is None else f"{f:.3f}"

    empty = {"stated scene": m.get("empty_heldout_rms_rel"), "diagnosis": d.get("gap_after")}
    empty.update({f"scene fit, {k}": f["scores"]["empty_heldout_rms_rel"] for k, f in fits.items()})
    lines.append(row(f"empty tank, held-out drives <= {g if g is not None else float('nan'):.3f}", empty, g)
                 + f" {floor(m.get('empty_symmetric_floor', {}).get('rms_rel'))}"
                 + (" (all rows) |" if "empty_symmetric_floor" in m else " |"))
    for su, v in m.get("object_rms_rel", {}).items():
        vals, fitted = {"stated scene": v}, set()
        for k, f in fits.items():
            sc = f["scores"]["setups"].get(su)
            if sc is not None:
                vals[f"scene fit, {k}"] = sc["rms_rel"]
                if not sc["held_out"]:
                    fitted.add(f"scene fit, {k}")
        lines.append(row(f"{su} signal <= {OBJECT_GOAL_REL:g}", vals, OBJECT_GOAL_REL, fitted)
                     + f" {floor(m.get('object_symmetric_floor', {}).get(su, {}).get('object_rms_rel_floor'))} |")
    shrink = {}
    if d.get("gap_before") and "gap_after" in d:
        shrink["diagnosis"] = 1 - d["gap_after"] / d["gap_before"]
    if m.get("empty_heldout_rms_rel"):
        shrink.update({f"scene fit, {k}": 1 - f["scores"]["empty_heldout_rms_rel"] / m["empty_heldout_rms_rel"]
                       for k, f in fits.items()})
    if shrink:
        lines.append(row(f"the gap shrunk >= {100 * SHRINK_GOAL:.0f} %", shrink, SHRINK_GOAL, larger_is_better=True)
                     + "  |")
    return "\n".join(lines)


def empty_tank_figure(folder, Z_measured, Z_fitted, train, rec) -> Path:
    """Measured V/I against BEM x fitted scale (fitted and held-out drives); histogram of reciprocity (%)."""
    fig, ax = new_figure(1, 2, panel_size_in=(5.0, 4.2))
    a, b = ax[0]
    a.loglog(Z_measured[train], Z_fitted[train], "o", ms=3, label="fitted drives (even)")
    a.loglog(Z_measured[~train], Z_fitted[~train], "s", ms=3, mfc="none", label="held-out drives (odd)")
    lim = [Z_measured.min() * 0.8, Z_measured.max() * 1.2]
    a.plot(lim, lim, "k-", lw=0.8)
    a.set(xlabel="measured V/I (system units)", ylabel="BEM x fitted scale", title="empty tank")
    a.legend()
    b.hist(100 * rec, bins=30)
    b.set(xlabel="reciprocal pair difference (%)", ylabel="pairs", title="measurement's own floor (reciprocity)")
    return save(fig, Path(folder) / "empty_tank.png")


def difference_signals_figure(folder, signals: dict) -> Path | None:
    """Each set-up's difference signal (with / without - 1, %): ``signals`` {set-up: (measured, simulated)}."""
    if not signals:
        return None
    fig, axes = new_figure(len(signals), 1, panel_size_in=(10.0, 2.6))
    for a, (name, (dm, ds)) in zip(axes[:, 0], signals.items()):
        a.plot(100 * dm, "k.-", lw=0.6, ms=3, label="measured")
        a.plot(100 * ds, "r.-", lw=0.6, ms=3, label="BEM")
        a.set(ylabel="with/without - 1 (%)", title=f"set-up {name}")
        a.legend(loc="upper left", fontsize=8, ncol=2)
    axes[-1, 0].set_xlabel("measurement (drive-major, drive-touching pairs left out)")
    return save(fig, Path(folder) / "difference_signals.png")


def geometry_figure(folder, offsets, resid: dict, one: dict | None) -> Path:
    """Model / measured - 1 by ring offset (each half held out in turn) for the stated tank and the shape
    candidates in ``resid``; with ``one`` (:func:`~validation.diagnosis.transfer.one_geometry`), the ring radius
    the empty tank and each ball want."""
    fig, ax = new_figure(1, 2 if one else 1, panel_size_in=(5.5, 4.2) if one else (6.0, 4.2))
    a = ax[0, 0]
    offs = np.unique(offsets)
    for name, mk in (("stated geometry", "ko-"), ("ring_radius", "bs-"), ("wall_taper", "cd--"),
                     ("water_depth", "r^-")):
        if name in resid:
            r = resid[name]
            a.plot(offs, [100 * np.mean(r[offsets == o]) for o in offs], mk, ms=4, lw=1, label=name.replace("_", " "))
    r0 = resid["stated geometry"]
    a.plot(offsets + 0.15 * (np.random.default_rng(0).random(len(offsets)) - 0.5), 100 * r0, ".", color="0.7", ms=2,
           zorder=0, label="each measurement (stated)")
    a.axhline(0, color="k", lw=0.5)
    a.set(xlabel="ring offset of the measurement pair from the drive pair", ylabel="model / measured - 1 (%)",
          title="empty tank: mean by offset, each half held out in turn")
    a.set_ylim(-30, 30)
    a.legend(fontsize=8)
    if one:
        b = ax[0, 1]
        items = [("stated", one["ring_radius_m_stated"]), ("empty tank fit", one["ring_radius_m_for_empty_tank"])] + [
            (f"ball amplitude {k}", v) for k, v in one["ring_radius_m_for_ball_amplitude"].items()]
        colours = ["0.4", "b"] + ["r"] * (len(items) - 2)
        for i, ((_, v), c) in enumerate(zip(items, colours)):
            b.plot(100 * v, i, "o", color=c, ms=8)
            b.annotate(f"{100 * v:.1f}", (100 * v, i), textcoords="offset points", xytext=(8, -4), fontsize=9)
        b.axvline(100 * one["ring_radius_m_stated"], color="0.4", lw=0.8, ls=":")
        b.set_yticks(range(len(items)), [k for k, _ in items])
        b.set_ylim(-0.6, len(items) - 0.4)
        b.set_xlim(100 * min(v for _, v in items) - 1, 100 * max(v for _, v in items) + 1.5)
        b.grid(axis="x", lw=0.3)
        b.set(xlabel="radius of the electrode ring (cm)", title="one tank shape for both? (ring radius wanted)")
    return save(fig, Path(folder) / "geometry.png")


def remainder_figure(folder, before: dict, after: dict, chosen: str) -> Path:
    """Where the held-out gap lies, before any effect and after ``chosen`` (a label: the named combination, or the
    nearest one where nothing is named): shares of the parts (stacked, of the squared gap) and, on an even ring,
    the mean by (drive, measurement) pair parity class."""
    parity = before.get("by_pair_parity") and after.get("by_pair_parity")
    fig, ax = new_figure(1, 2 if parity else 1, panel_size_in=(5.2, 3.8))
    a = ax[0, 0]
    labels = ["stated geometry", chosen.replace("+", "+\n")]
    colours = {"by_ring_offset": "tab:blue", "shared_by_reciprocal_pairs": "tab:orange", "noise": "tab:gray",
               "unpaired": "0.85"}
    for i, split in enumerate((before, after)):
        bottom = 0.0
        for part, c in colours.items():
            v = 100 * split["shares"][part] * split["rms_rel"] ** 2 / before["rms_rel"] ** 2
            label = {"shared_by_reciprocal_pairs": "shared by reciprocal\npairs, beyond noise",
                     "noise": "noise (breaks\nreciprocity, x2)"}.get(part, part.replace("_", " "))
            a.bar(i, v, bottom=bottom, color=c, width=0.6, label=label if i == 0 else None)
            bottom += v
        a.annotate(f"RMS {100 * split['rms_rel']:.1f} %", (i, bottom), textcoords="offset points", xytext=(0, 3),
                   ha="center", fontsize=9)
    a.set_xticks([0, 1], labels, fontsize=8)
    a.set_xlim(-0.6, 3.4)
    a.set_ylim(0, 115)
    a.set(ylabel="share of the stated geometry's squared gap (%)", title="where the held-out gap lies")
    a.legend(fontsize=7, loc="center right")
    if parity:
        b = ax[0, 1]
        keys = list(before["by_pair_parity"])
        x = np.arange(len(keys))
        b.bar(x - 0.2, [100 * before["by_pair_parity"][k] for k in keys], 0.4, color="k", label="stated geometry")
        b.bar(x + 0.2, [100 * after["by_pair_parity"][k] for k in keys], 0.4, color="tab:red", label=chosen)
        b.axhline(0, color="k", lw=0.5)
        b.set_xticks(x, [f"drive {k[0]}\nmeasure {k[1]}" for k in keys], fontsize=8)
        b.set(ylabel="mean of model / measured - 1 (%)\n(each offset's mean removed)",
              title="by pair parity along the ring (e even, o odd)")
        b.legend(fontsize=8)
    return save(fig, Path(folder) / "remainder.png")


def candidates_figure(folder, diagnosis: dict, floor_rel: float, stated_heldout_rel: float) -> Path | None:
    """What each candidate explains: its RMS gap on the held-out (odd) drives and, fitted on the empty tank, on the
    object set-ups, against the stated geometry's on each (``stated_heldout_rel``: the comparison's
    ``empty_heldout_rms_rel``, the same folds as the candidates') and the measurement's own floor (per
    measurement, reciprocity). None when no candidate was scored on object set-ups."""
    cands = {k: v for k, v in diagnosis["candidates"].items() if "heldout_setups" in v}
    stated = diagnosis.get("stated_geometry_heldout_setups")
    if not cands or not stated:
        return None
    names = sorted(cands, key=lambda k: -cands[k]["heldout_setups"]["empty_to_objects_rms_rel"])
    y = np.arange(len(names))
    fig, ax = new_figure(1, 1, panel_size_in=(8.5, 1.8 + 0.26 * len(names)))
    a = ax[0, 0]
    a.barh(y + 0.2, [100 * cands[k]["heldout_rms_rel"] for k in names], 0.4, color="0.7",
           label="held-out (odd) drives")
    a.barh(y - 0.2, [100 * cands[k]["heldout_setups"]["empty_to_objects_rms_rel"] for k in names], 0.4,
           color="tab:blue", label="object set-ups, fitted on the empty tank")
    a.axvline(100 * stated_heldout_rel, color="0.4", ls="--", lw=1, label="stated geometry, held-out (odd) drives")
    a.axvline(100 * stated["empty_to_objects_rms_rel"], color="tab:blue", ls="--", lw=1,
              label="stated geometry, object set-ups")
    a.axvline(100 * floor_rel, color="k", lw=1.2, label="floor per measurement (reciprocity)")
    a.set_yticks(y, [f"{k} ({cands[k]['n_parameters']})" for k in names], fontsize=8)
    a.set_ylim(-0.7, len(names) - 0.3)
    a.set(xlabel="RMS of model / measured - 1 (%)", title="what each candidate explains (its parameters in brackets)")
    a.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=2)
    return save(fig, Path(folder) / "candidates.png")


def study_mesh_words(mesh: dict | None) -> str:
    """How the study's mesh was chosen, in words (:func:`~electrosense.validation.comparison.study_mesh.study_bem_options`).

    >>> study_mesh_words({"chosen": 1, "threshold_rel": 0.006, "levels": [{"error_rms_rel": 0.0071},
    ...                                                                  {"error_rms_rel": 0.0052}]})
    'no [bem] table: mesh level 1 of the ladder, its error 0.52 % against 0.60 % (0.5x the noise)'
    >>> study_mesh_words({"chosen": "stated"})
    "the scene file's [bem] table"
    """
    if not mesh or mesh.get("chosen") == "stated":
        return "the scene file's [bem] table"
    if mesh["chosen"] == "defaults":
        return f"no [bem] table: the solver's defaults, no coarser mesh's error within {BEM_ERROR_OVER_NOISE:g}x the noise"
    k = mesh["chosen"]
    return (f"no [bem] table: mesh level {k} of the ladder, its error {100 * mesh['levels'][k]['error_rms_rel']:.2f} % "
            f"against {100 * mesh['threshold_rel']:.2f} % ({BEM_ERROR_OVER_NOISE:g}x the noise)")


def report_markdown(m: dict) -> str:
    """The report (markdown) of a metrics dict written by the transfer comparison."""
    lines = ["# Real tank: BEM against the measured phantom", "",
             (f"Data {m['data']}, scene {m['scene']}, BEM {m['bem']['triangles']} triangles "
              f"({study_mesh_words(m['bem'].get('mesh'))}); wall {m['wall_s']:.0f} s, CPU {m['cpu_s']:.0f} s."), "",
             "The goals beside what the stated scene, the diagnosis and the scene fits reach (details below):", "",
             goals_table(m), "",
             (f"- Noise floor (reciprocity): RMS {m['noise_floor']['reciprocity_rms_rel']:.4f} per reciprocal pair, "
              f"~{m['noise_floor']['per_measurement_rms_rel']:.4f} per measurement; with a gain per electrode pair "
              f"driving and another measuring fitted to it: {m['noise_floor']['pair_gains']['rms_rel_after']:.4f}."),
             *([f"  A crosstalk differing between the mixed multiplexer classes (even-odd less odd-even: "
                f"{m['noise_floor']['parity_offsets']['difference_ohm']:.3g} +- "
                f"{m['noise_floor']['parity_offsets']['standard_error_ohm']:.2g} ohm, p = "
                f"{m['noise_floor']['parity_offsets']['p_value']:.2g}) leaves "
                f"{m['noise_floor']['parity_offsets']['rms_rel_after']:.4f} per reciprocal pair."]
               if "parity_offsets" in m["noise_floor"] else []),
             (f"  The noise per measurement the diagnosis and the scene fit assume: "
              f"{m['noise_floor'].get('fit_noise_rel', m['noise_floor']['per_measurement_rms_rel']):.4f} "
              f"(from {m['noise_floor'].get('fit_noise_from', 'the reciprocity floor')})."),
             (f"- Empty tank, held-out drives: empty_heldout_rms_rel = {m['empty_heldout_rms_rel']:.4f} (goal <= "
              f"{empty_tank_goal(m) or float('nan'):.4f}, {EMPTY_FLOOR_FACTOR:g}x the floor per measurement)."),
             f"  Both halves held out in turn (2-fold): {m['empty_twofold_rms_rel']:.4f}.",
             *([f"  Any scene with the tank's {m['empty_symmetric_floor']['symmetries']} symmetries, read through one "
                f"gain, leaves at least {m['empty_symmetric_floor']['rms_rel']:.4f} on all rows (the spread of log|Z| "
                "over each row's images): below it only what breaks the symmetry fits (electrodes' places, the "
                "instrument's channels)."] if "empty_symmetric_floor" in m else []),
             f"- Balls: height fitted {m['ball_height']['fitted_z_m']:.3f} m (assumed {m['ball_height']['assumed_z_m']:.3f} m)."
             + "".join(f" Not stated in the scene's [protocol], taken: {t}." for t in m['ball_height'].get('not_stated', [])),
             *[f"- Set-up {k}: object_rms_rel = {v:.3f} at the fitted height, "
               f"{m['object_rms_rel_at_assumed_height'][k]:.3f} at the assumed one (goal <= {OBJECT_GOAL_REL:g}); measured/BEM "
               f"amplitude {m['ball_height']['measured_over_simulated_amplitude'][k]:.2f}"
               for k, v in m["object_rms_rel"].items()],
             *[f"  {k}: its scene and balls share {v['symmetries'] - 1} "
               f"symmetr{'y' if v['symmetries'] == 2 else 'ies'} besides the identity, so any scene "
               f"with them leaves at least {v['object_rms_rel_floor']:.3f} of its signal (the spread over each row's "
               f"images; its noise, from reciprocity, {v['signal_noise_rel']:.3f})"
               for k, v in m.get("object_symmetric_floor", {}).items()]]
    if "error" in m.get("diagnosis", {}):
        lines += [f"- Diagnosis: {m['diagnosis']['error']}."]
    elif "diagnosis" in m:
        d = m["diagnosis"]
        e = d.get("engine", {})
        det = e.get("detection", {})
        named = (f"nothing named (nearest: {e['combination']})" if d["chosen"] == "unexplained" and e
                 else f"chosen {d['chosen']}")
        lines += [(f"- Diagnosis ({d.get('verdict', '')}): {named}, held-out gap {d['gap_before']:.4f} "
                   f"-> {d['gap_after']:.4f} ({100 * d['shrink']:.0f} % shrink; goal >= {100 * SHRINK_GOAL:.0f} %)."),
                  *([f"  - the engine: {e['engine']}; {e['noise_model']}; detection: best improvement "
                     f"{det['improvement']:.1f} noise variances against a threshold of "
                     f"{det['improvement_threshold']:.1f} "
                     f"(p = {det['p_detection']:.3g})"] if det else []),
                  *[f"  - {name}.{p} = {v:.4g} (95 % interval {lo:.4g} to {hi:.4g})"
                    for name, ps in e.get("parameters", {}).items() for p, v in ps.items()
                    for lo, hi in [e["interval_95"][name][p]]],
                  *[f"  - {s['effect']} made exact on the BEM at its fitted scene: held-out "
                    f"{s['heldout_rms_rel_linear']:.4f} (linear) -> {s['heldout_rms_rel']:.4f} in "
                    f"{len(s['solves'])} solve(s)" for s in e.get("bem_secants", [])],
                  "  - the linear candidates about the one solve, scored on the odd drives (the table below):",
                  *([f"  - stated geometry fitted on the empty tank, object set-ups predicted: "
                     f"{d['stated_geometry_heldout_setups']['empty_to_objects_rms_rel']:.4f}"]
                    if d.get("stated_geometry_heldout_setups") else []),
                  *[f"  - {k} ({v['n_parameters']} parameters): held-out {v['heldout_rms_rel']:.4f}, "
                    f"2-fold {v['twofold_rms_rel']:.4f}"
                    + (f", object set-ups from the empty tank {v['heldout_setups']['empty_to_objects_rms_rel']:.4f}"
                       if "heldout_setups" in v else "")
                    + "".join(f"; {n}" for n in v.get("notes", []))
                    for k, v in d["candidates"].items()],
                  *[f"  - {k}: not scored, its changed scene is not a valid one ({why})"
                    for k, why in d.get("skipped", {}).items()],
                  f"  - where the gap lies before any effect (stated geometry): {d['gap_before_split']['text']}.",
                  *([f"  - where the rest lies (after {e.get('combination', d['chosen'])}"
                     + (", not named" if d["chosen"] == "unexplained" else "") + f"): {d['remaining']['text']}."]
                    if d["chosen"] != "none" else [f"  - {d['rule']}."])]
        if "error" in d.get("one_geometry", {}):
            lines += [f"- One tank shape for both? {d['one_geometry']['error']}."]
        elif "one_geometry" in d:
            g = d["one_geometry"]
            lines += [f"- One tank shape for both? Ring radius stated {100 * g['ring_radius_m_stated']:.1f} cm; the "
                      f"empty tank's held-out fit wants {100 * g['ring_radius_m_for_empty_tank']:.1f} cm (held-out "
                      f"{g['empty_heldout_rms_rel_with_ring_radius']:.4f}); the balls' amplitudes (ball radius "
                      f"{1e3 * g['ball_radius_m']:.2f} mm) want " + ", ".join(
                          f"{k} {100 * v:.1f} cm" for k, v in g["ring_radius_m_for_ball_amplitude"].items()) + "."]
    else:
        lines += ["- Diagnosis: not run (--no-diagnosis)."]
    lines += ["", "![empty tank](empty_tank.png)", "", "![tank shape](geometry.png)", "",
              *(["![where the gap lies](remainder.png)", ""] if "remaining" in m.get("diagnosis", {}) else []),
              *(["![what each candidate explains](candidates.png)", ""]
                if m.get("diagnosis", {}).get("stated_geometry_heldout_setups") else []),
              "![difference signals](difference_signals.png)", ""]
    return "\n".join(lines)


def summary_text(m: dict) -> str:
    """The headline numbers (noise floor, empty tank, objects, diagnosis) and the goals beside them."""
    lines = [json.dumps({k: m[k] for k in ("noise_floor", "empty_heldout_rms_rel", "object_rms_rel")}, indent=1)]
    if "diagnosis" in m:
        lines.append(f"diagnosis: {({k: m['diagnosis'][k] for k in ('chosen', 'gap_before', 'gap_after', 'error') if k in m['diagnosis']})}")
    if "scene_fit" in m:
        from electrosense.validation.diagnosis.tank_scene_fit import scene_fit_summary

        lines.append(scene_fit_summary(m["scene_fit"]))
    return "\n".join(lines + [goals_text(m), goals_table(m)])


def write_transfer_report(folder, comparison, metrics: dict, resid: dict | None = None) -> Path:
    """Every figure and ``report.md`` of a comparison (:class:`electrosense.validation.comparison.transfer.TransferComparison`).

    ``resid``: 2-fold residuals of the diagnosis' candidates by name (with
    ``"stated geometry"``); None: the stated geometry's only.
    """
    folder = Path(folder)
    c = comparison
    empty_tank_figure(folder, c.Z_measured_ohm, c.scale * c.Z_model_ohm, ~c.held_out, c.reciprocity)
    difference_signals_figure(folder, c.signals)
    one_geometry = metrics.get("diagnosis", {}).get("one_geometry")
    if c.offsets is not None:
        geometry_figure(folder, c.offsets, resid or {"stated geometry": c.residual},
                        None if one_geometry is None or "error" in one_geometry else one_geometry)
    if "remaining" in metrics.get("diagnosis", {}):
        d = metrics["diagnosis"]
        label = d["chosen"] if d["chosen"] != "unexplained" else \
            f"nearest (not named):\n{d.get('engine', {}).get('combination', '?')}"
        remainder_figure(folder, d["gap_before_split"], d["remaining"], label)
        candidates_figure(folder, d, metrics["noise_floor"]["per_measurement_rms_rel"], metrics["empty_heldout_rms_rel"])
    path = folder / "report.md"
    text = report_markdown(metrics)
    if "scene_fit" in metrics:
        from electrosense.validation.diagnosis.tank_scene_fit import scene_fit_markdown

        text += "\n" + scene_fit_markdown(metrics["scene_fit"])
    path.write_text(text)
    return path
