"""The diagnosis written out: ``diagnosis.json`` and an offline ``index.html`` with figures.

The page reuses the validation report's machinery (:mod:`electrosense.validation.report.html`
for the page, :mod:`electrosense.validation.report.figures` for the curves and bars).

``diagnosis.json`` holds at least

* ``gap_before``, ``gap_after``: RMS relative gap on held-out data, before and
  after the chosen effect(s); ``gap_before_region``, ``gap_after_region``: the
  same in the region where the gap concentrates; ``noise``: the measurement
  noise estimated from the data;
* ``where``: the breakdowns (receiver, place, time, heading, pass) with the
  share of the squared gap, and ``concentration``;
* ``ranking``: every candidate alone: ``effect``, ``form``, ``params``,
  ``uncertainty`` (1 sigma), ``heldout_gap``, ``shrink`` (1 - gap after /
  gap before, held-out), the same in the region, the penalised score;
* ``chosen``: the effect names (``["none"]`` when the gap is noise);
  ``combination``: the fitted chosen combination;
* ``confusable``: pairs that these data cannot tell apart, with the reason
  and the measurement that would separate them.

Example
-------
>>> from electrosense.validation.diagnosis.report import write_report  # doctest: +SKIP
>>> write_report(diagnosis, "out/")  # doctest: +SKIP
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from electrosense.validation.diagnosis.pipeline import Diagnosis
from electrosense.validation.diagnosis.select import CandidateScore

__all__ = ["diagnosis_dict", "write_json", "write_report"]


def _clean(x):
    """JSON-safe: numpy to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _excess_shrink(before: float, after: float, noise: float) -> float | None:
    """1 - (gap above the noise after) / (gap above the noise before), gaps combined in quadrature."""
    excess = before**2 - noise**2
    if excess <= 0:
        return None
    return 1 - math.sqrt(max(after**2 - noise**2, 0.0) / excess)


def _derived(name: str, params: dict, d: Diagnosis) -> dict:
    """Readable consequences of the parameters (the true conductivity, the sphere's radius...)."""
    out = {}
    if name == "conductivity":
        out["sigma_true_S_per_m"] = d.obs.sigma_S_per_m * (1 + params["sigma_rel_change"])
    elif name == "unmodelled_object":
        m = params["dipole_m3"]
        out["radius_if_conducting_m"] = float(max(m, 0.0) ** (1 / 3)) if m > 0 else None
        out["radius_if_insulating_m"] = float((-2 * m) ** (1 / 3)) if m < 0 else None
        out["kind"] = "more conducting than water" if m > 0 else "less conducting than water"
    elif name == "water_depth" and d.obs.tank is not None:
        if "d_surface_m" in params:
            out["water_depth_true_m"] = d.obs.tank.water_depth_m + params["d_surface_m"]
        else:
            out["water_depth_true_m"] = d.obs.tank.water_depth_m - params["d_floor_m"]
    elif name == "tank_size" and d.obs.tank is not None:
        out["Lx_true_m"] = d.obs.tank.size_m[0] + params.get("dLx_m", 0.0)
        out["Ly_true_m"] = d.obs.tank.size_m[1] + params.get("dLy_m", 0.0)
    return out


def readable_estimate(value: float, sd: float, unit: str = "", span: float | None = None) -> str:
    """A parameter and its 1-sigma as a person reads it: the digits the uncertainty allows, or "not determined".

    >>> readable_estimate(-0.025123, 0.00041)
    '-0.0251 +- 0.0004'
    >>> readable_estimate(7.867e-07, 3.7e2, "rad", span=0.4)
    'not determined by these data (1-sigma 3.7e+02 rad, wider than the plausible range 0.4 rad)'
    """
    u = f" {unit}" if unit and unit != "1" else ""
    if not np.isfinite(sd) or (span is not None and sd > 0.5 * span):
        return f"not determined by these data (1-sigma {sd:.2g}{u}, wider than the plausible range {span:.2g}{u})"
    if sd <= 0:
        return f"{value:.4g}{u}"
    digits = max(0, -int(math.floor(math.log10(sd))))
    if abs(value) >= 1e4 or (0 < abs(value) < 1e-3 and sd < 1e-3):
        return f"{value:.3e} +- {sd:.1e}{u}"
    return f"{value:.{digits}f} +- {sd:.{digits}f}{u}"


def readable_shrink(before: float, after: float) -> str:
    """``"92 % of the gap removed"``, or ``"gap 3.1x larger"`` when a candidate makes it worse.

    >>> readable_shrink(0.02, 0.0016), readable_shrink(0.001, 0.1047)
    ('92 % of the gap removed', 'gap 105x larger (worse than nothing)')
    """
    if before <= 0:
        return "no gap"
    if after <= before:
        return f"{100 * (1 - after / before):.0f} % of the gap removed"
    return f"gap {after / before:.3g}x larger (worse than nothing)"


def _readable_params(c: CandidateScore) -> dict:
    out, i = {}, 0
    sd = np.sqrt(np.clip(np.diag(c.fit.cov), 0, None)) if c.fit.cov.size else np.zeros(0)
    for e in c.effects:
        for j, p in enumerate(e.param_names):
            key = p if len(c.effects) == 1 else f"{e.name}.{p}"
            out[key] = readable_estimate(float(c.fit.theta[i + j]), float(sd[i + j]), e.units[j],
                                         float(e.upper[j] - e.lower[j]))
        i += e.n_params
    return out


def _intervals(params: dict, sd: dict) -> dict:
    """95 % confidence intervals (normal approximation at the optimum) of every parameter, nested like ``params``.

    >>> _intervals({"a": 1.0}, {"a": 0.5})
    {'a': [0.02001800773, 1.97998199227]}
    """
    out = {}
    for k, v in params.items():
        if isinstance(v, dict):
            out[k] = _intervals(v, sd.get(k, {}))
        else:
            e = 1.959963984540054 * float(sd.get(k, np.nan))
            out[k] = [round(v - e, 12), round(v + e, 12)]
    return out


def _candidate_row(c: CandidateScore, d: Diagnosis) -> dict:
    before, before_r = d.gap_before, d.baseline.region_gap
    params = c.fit.params()
    name = c.name
    p = params.get(name, {}) if len(c.effects) == 1 else params
    u = c.fit.uncertainty().get(name, {}) if len(c.effects) == 1 else c.fit.uncertainty()
    row = {
        "effect": name,
        "form": c.effects[0].form if len(c.effects) == 1 else [e.form for e in c.effects],
        "params": p,
        "uncertainty": u,
        "interval_95": _intervals(p, u),
        "n_params": c.n_params,
        "heldout_gap": c.heldout_gap,
        "heldout_by": ("whole passes" if c.folds is d.folds or not c.folds else "contiguous segments of every pass"),
        "shrink": 1 - c.heldout_gap / before if before > 0 else 0.0,
        "shrink_text": readable_shrink(before, c.heldout_gap),
        "readable": _readable_params(c),
        "heldout_gap_region": c.region_gap,
        "shrink_region": (1 - c.region_gap / before_r) if (before_r and c.region_gap is not None) else None,
        "train_gap": c.fit.train_rms,
        "at_bound": c.at_bound,
        "score": c.score,
        "delta_score_vs_none": c.score - d.baseline.score,
        "fit": c.fit.message,
    }
    if len(c.effects) == 1:
        row["derived"] = _derived(name, p, d)
        row["describe"] = c.effects[0].describe
    return row


def diagnosis_dict(d: Diagnosis) -> dict:
    """Everything of ``d`` as a JSON-ready dict."""
    where = {k: v for k, v in d.where.items() if k != "labels"}
    final = d.final
    before_r, after_r = d.baseline.region_gap, final.region_gap
    out = {
        "tool": "esense diagnose",
        "model": d.model,
        "effect_model": d.effect_model,
        "source": d.obs.source,
        "n_poses": d.obs.n_poses,
        "n_passes": int(len(np.unique(d.obs.passes))),
        "receivers": list(d.obs.sensor.receivers),
        "noise": d.noise,
        "gap_before": d.gap_before,
        "gap_after": d.gap_after,
        "shrink": 1 - d.gap_after / d.gap_before if d.gap_before > 0 else 0.0,
        "shrink_above_noise": _excess_shrink(d.gap_before, d.gap_after, d.noise),
        "gap_before_region": before_r,
        "gap_after_region": after_r,
        "region": {"axis": d.where["concentration"]["axis"], "group": d.where["concentration"]["group"]},
        "verdict": d.selection.verdict,
        "chosen": d.chosen,
        "nearest": d.selection.chosen[-1].name if d.selection.chosen else None,
        "noise_floor": d.noise_floor,
        "model_error": d.model_error,
        "ambiguity": d.ambiguity,
        "bem_check": d.bem_check,
        "detection": {k: v for k, v in (d.detection or {}).items() if k != "null_sse"} or None,
        "combination": _candidate_row(final, d) if d.selection.chosen else None,
        "where": where,
        "model_split": d.model_split,
        "ranking": [_candidate_row(c, d) for c in d.ranking],
        "selection_steps": d.selection.steps,
        "confusable": d.confusable,
        "heldout": {"folds": len(d.folds),
                    "kind": "passes" if len(np.unique(d.obs.passes)) >= 3 else "contiguous segments of each pass"},
        "definitions": {
            "gap": "RMS over held-out samples and receivers of (bench - simulation) / |simulation|",
            "shrink": "1 - heldout_gap / gap_before",
            "shrink_above_noise": "1 - sqrt(gap_after^2 - noise^2) / sqrt(gap_before^2 - noise^2)",
            "score": "SSE_heldout / noise^2 + n_params ln(N) (lower is better)",
            "noise": "robust spread of second differences of the residual along each pass / sqrt(6)",
        },
        "notes": d.notes,
        "seconds": d.seconds,
    }
    return _clean(out)


def _bem_check_text(check: dict | None) -> str:
    if not check:
        return ("not needed (the chosen effect is exact in any model: conductivity, drift, channel gains) or no "
                "effect was named")
    verdict = "confirms" if check["confirmed"] else "does NOT confirm"
    return (f"The BEM {verdict} {check['effect']}: at {len(check['poses'])} of the baseline's BEM poses the gap is "
            f"{100 * check['gap_before']:.3g} % before, {100 * check['gap_effect_model']:.3g} % with the effect model's "
            f"prediction and {100 * check['gap_bem']:.3g} % with the BEM's"
            + (f"; with the parameters refined on the BEM ({', '.join(f'{k} = {v:.4g}' for k, v in check['params_bem'].items())}) "
               f"{100 * check['gap_bem_refined']:.3g} %" if "params_bem" in check else "") + f". {check['how'][:1].upper()}{check['how'][1:]}.")


def write_json(d: Diagnosis, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(diagnosis_dict(d), indent=2) + "\n")
    return path


def _figures(d: Diagnosis, folder: Path, vector: str | None = None) -> list:
    """Residual along the path (before/after, per receiver, one row per pass), the gap by place, the ranking.

    Residuals are shown as simulation / bench - 1, the sign convention of every
    report figure (the diagnosis itself works with r = bench / simulation - 1:
    simulation / bench - 1 = -r / (1 + r)).
    """
    from electrosense.validation.report.figures import Panel, Series, bar_figure, curves_figure, path_coordinate
    from electrosense.validation.report.html import Figure
    from electrosense.validation.report.style import RELATIVE_ERROR_LABEL

    def sim_over_bench(r):
        return 100 * (-r / (1 + r))

    figs = []
    after = d.final.heldout
    labels = list(np.unique(d.obs.passes))
    indices = d.obs.pass_indices()
    band = (-100 * d.noise, 100 * d.noise, "noise (1 sigma)")
    panels = []
    for p, idx in zip(labels, indices):
        x, xlabel = path_coordinate(d.obs.poses[idx])
        prefix = f"pass {p}, " if len(labels) > 1 else ""
        for j, k in enumerate(d.obs.sensor.receivers):
            series = [Series(x, sim_over_bench(d.r0[idx, j]), "before", "scatter", "#7f7f7f"),
                      Series(x, sim_over_bench(after[idx, j]), "after " + "+".join(d.chosen), "scatter", "#d9541a")]
            panels.append(Panel(f"{prefix}receiver {k}", xlabel, RELATIVE_ERROR_LABEL, series, zero_line=True,
                                band=band))
    values = np.concatenate([s.y for p in panels for s in p.series] + [np.array(band[:2])])
    values = values[np.isfinite(values)]
    if values.size:
        span = float(values.max() - values.min()) or 1.0
        for panel in panels:
            panel.y_range = (float(values.min()) - 0.06 * span, float(values.max()) + 0.06 * span)
    figs.append(Figure(curves_figure(panels, folder / "residual_along_path.png", ncols=len(d.obs.sensor.receivers),
                                     share_y=True, vector=vector),
                       "relative residual along the path, simulation / bench - 1, before and after the chosen "
                       "effect(s) (held-out predictions), one row per pass; grey band: the noise level"))
    table = d.where["by_place"]
    if len(table) >= 1:
        figs.append(Figure(bar_figure([r["group"] for r in table],
                                      {"share of the squared gap": [r["share"] for r in table],
                                       "share of the samples": [r["fraction"] for r in table]},
                                      folder / "gap_by_place.png", "where the gap lies", "share", log=False,
                                      counts=[r["n"] for r in table], vector=vector),
                           "share of the squared gap by place, against the share of the samples there "
                           "(n: samples in the place)"))
    names = [c.name.replace("_", " ") for c in d.ranking]
    figs.append(Figure(bar_figure(names, {"held-out gap": [100 * c.heldout_gap for c in d.ranking]},
                                  folder / "ranking.png", "candidates alone", "held-out RMS gap (%)",
                                  horizontal=True,
                                  lines={"gap before": 100 * d.gap_before, "noise (1 sigma)": 100 * d.noise},
                                  vector=vector),
                       "held-out gap left by each candidate alone (best first), against the gap before and the "
                       "noise level; a logarithmic axis when the gaps span more than a factor 30"))
    return figs


def write_report(d: Diagnosis, outdir, figures: bool = True, vector: str | None = None) -> Path:
    """Write ``diagnosis.json`` and ``index.html`` (with figures unless ``figures=False``) into ``outdir``.

    The figures are PNGs for the page; ``vector="pdf"`` (or ``"svg"``) writes a vector copy beside each, for a
    paper (it doubles the figures' time, about 2.5 s of a later log's 20)."""
    from electrosense.validation.report.html import Section, Table, write_html

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(d, out / "diagnosis.json")
    dd = diagnosis_dict(d)
    pct = lambda v: None if v is None else 100 * v  # noqa: E731
    notes = list(d.notes)
    figs = []
    if figures:
        try:
            figs = _figures(d, out, vector)
        except Exception as exc:  # a figure must never cost the diagnosis
            notes.append(f"figures not drawn: {exc}")
    summary = Table(
        ["quantity", "value"],
        [["chosen", ", ".join(dd["chosen"]) or "(nothing)"], ["verdict", dd["verdict"]],
         ["noise (%)", pct(dd["noise"])],
         ["baseline's own error (%)", "unknown" if dd["model_error"].get("baseline_rms") is None
          else pct(dd["model_error"]["baseline_rms"])],
         ["noise floor (%)", pct(dd["noise_floor"])],
         ["gap before (held-out, %)", pct(dd["gap_before"])],
         ["gap after (held-out, %)", pct(dd["gap_after"])], ["shrink", readable_shrink(dd["gap_before"], dd["gap_after"])],
         [f"gap before in {dd['region']['group']} (%)", pct(dd["gap_before_region"])],
         [f"gap after in {dd['region']['group']} (%)", pct(dd["gap_after_region"])]],
        caption="verdict",
    )
    ranking = Table(
        ["effect", "form", "parameters (1-sigma)", "held-out gap (%)", "shrink", "score - none"],
        [[r["effect"], r["form"], "; ".join(f"{k} = {v}" for k, v in r["readable"].items()),
          pct(r["heldout_gap"]), r["shrink_text"], r["delta_score_vs_none"]] for r in dd["ranking"]],
        caption="every candidate alone, best first",
    )
    where_tables = [
        Table(["group", "n", "RMS (%)", "mean, simulation / bench - 1 (%)", "share", "enrichment"],
              [[str(r["group"]), r["n"], pct(r["rms"]), pct(-r["mean"] / (1.0 + r["mean"])), r["share"],
                r["enrichment"]]
               for r in dd["where"][key]], caption=key.replace("_", " "))
        for key in ("by_receiver", "by_place", "by_time", "by_heading", "by_pass")
    ]
    c = dd["where"]["concentration"]
    where_text = (f"The gap concentrates in {c['axis']} = {c['group']}: {100 * c['share']:.0f} % of the squared gap "
                  f"on {100 * c['fraction']:.0f} % of the values. Time trend of the mean residual: "
                  f"{100 * dd['where']['time_trend']['slope_per_hour']:.3g} +- "
                  f"{100 * dd['where']['time_trend']['slope_stderr']:.2g} %/h.")
    me = dd["model_error"]
    budget_rows = [["bench noise", pct(dd["noise"])],
                   ["baseline error (" + str(me.get("baseline")) + ")",
                    "unknown" if me.get("baseline_rms") is None else pct(me["baseline_rms"])]]
    budget_rows += [[f"  baseline error at {g}", pct(v)] for g, v in (me.get("baseline_by_place") or {}).items()]
    budget_rows += [["noise floor", pct(dd["noise_floor"])]]
    budget = Table(["part", "RMS (%)"], budget_rows, caption="model-error budget")
    ambiguity = [f"{a['effect']} explains the data about as well as {dd['chosen'][0] if dd['chosen'] else '?'} "
                 f"(held-out gap {100 * a['heldout_gap']:.3g} %); to separate them: {a['separate_by']}."
                 for a in dd["ambiguity"]]
    sections = [
        Section("Verdict", tables=[summary], notes=notes),
        Section("Model-error budget", f"{me.get('how', '')}. {me.get('rule', '')}.", tables=[budget],
                notes=[f"BEM discretisation: {k}: {v}" for k, v in me.get("bem_discretisation", {}).items()]),
        Section("Ambiguity set", ambiguity or "no other candidate explains the data as well as the chosen one"),
        Section("The chosen effect solved by the BEM", _bem_check_text(dd.get("bem_check"))),
        Section("Where the gap lies", where_text, tables=where_tables, figures=figs[:2]),
        Section("Which effect", "Each candidate fitted on training samples and scored on held-out ones.",
                tables=[ranking], figures=figs[2:]),
        Section("Cannot be told apart", [f"{p['pair'][0]} / {p['pair'][1]}: {p['reason']}; to separate them: "
                                         f"{p['separate_by']}." for p in dd["confusable"]] or "no such pair"),
    ]
    if dd["model_split"]:
        s = dd["model_split"]
        sections.insert(2, Section("PSM approximation vs missing physics", tables=[Table(
            ["part", "RMS (%)", "share"],
            [["PSM vs BEM", pct(s["psm_vs_bem_rms"]), s["share_psm_approximation"]],
             ["bench vs BEM", pct(s["bench_vs_bem_rms"]), s["share_missing_physics"]]], caption="on a subsample of poses")]))
    write_html(out / "index.html", "Sim-to-real gap diagnosis", sections,
               intro=f"{d.obs.n_poses} poses, model {d.model}, effects evaluated with {d.effect_model}.",
               footer=f"esense diagnose, {d.seconds:.1f} s")
    return out / "index.html"
