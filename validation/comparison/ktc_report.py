"""The KTC study's report: ``report.md``, the figures, and the summary printed beside the goals."""
from __future__ import annotations

import math
from pathlib import Path

__all__ = ["summary_text", "write_ktc_report"]


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.1f} %"


def summary_text(m: dict) -> str:
    """The figures against the goals, a few lines."""
    lines = [f"empty tank, held-out patterns: {_pct(m['ref_rms_rel'])} (linear floor {_pct(m['ref_linear_floor_rel'])}, "
             f"{m['ref_rms_over_floor']:.2f}x; goal <= 1.5x)"]
    for k, v in m.get("fit_tanks", {}).items():
        lines.append(f"fit tank {k}: change fitted {_pct(v['fitted_rms_rel'])}, held out by tank "
                     f"{_pct(v['heldout_rms_rel'])} ({_pct(v['heldout_rms_rel_reference_water'])} with the reference's "
                     f"water; floor {_pct(v['difference_floor_rel'])}, drift {100 * v['drift']:+.2f} %)")
    for k, v in m.get("predicted", {}).items():
        if "error" in v:
            lines.append(f"predicted {k}: not modelled ({v['error']})")
            continue
        lines.append(f"predicted {k}: change {_pct(v['difference_rms_rel'])} of itself (floor "
                     f"{_pct(v['difference_floor_rel'])}; water {100 * v['water_change_rel']:+.2f} "
                     f"+- {100 * v['water_change_rel_se']:.2f} % since the reference, its two folds "
                     f"+- {100 * v['water_change_rel_fold_spread']:.2f} %; "
                     f"{_pct(v['difference_rms_rel_reference_water'])} with the reference's water), "
                     f"total {_pct(v['total_rms_rel'])}")
    s = m.get("predicted_summary")
    if s:
        lines.append(f"predicted changes: median {_pct(s['difference_rms_rel_median'])}, max "
                     f"{_pct(s['difference_rms_rel_max'])} over {s['files']} files (goal: median <= 15 %, none > 35 %); "
                     f"with the reference's water: median {_pct(s['reference_water_median'])}, max "
                     f"{_pct(s['reference_water_max'])}")
    sec = m.get("seconds", {})
    if "wall_s" in sec:
        lines.append(f"time: {sec['wall_s']:.0f} s wall, {sec['cpu_s']:.0f} s CPU")
    return "\n".join(lines)


def write_ktc_report(out_dir, metrics, fit, fit_folder, predictions, diag, figures=True, progress=print) -> Path:
    out = Path(out_dir)
    figs = []
    if figures:
        from electrosense.validation.comparison import ktc_figures

        progress("figures")
        figs = ktc_figures.all_figures(out, metrics, fit, fit_folder, predictions, diag)
    md = ["# KTC2023 tanks against the modal model", "", "```", summary_text(metrics), "```", ""]
    md += ["## Fitted unknowns", "", "| unknown | value | standard error | unit |", "|---|---|---|---|"]
    for name, v in metrics["fitted"].items():
        if name == "derived" or name.startswith("offset_ch") or name.startswith("log_zeta_e"):
            continue
        se = "not determined" if v["se"] is None else f"{v['se']:.4g}"
        md.append(f"| {name} | {v['value']:.4g} | {se} | {v['unit']} |")
    z = [metrics["fitted"][f"log_zeta_e{k}"] for k in range(1, 1 + len(metrics["fitted"]["derived"]
                                                                       ["contact_impedance_ohm_m2_if_mA"]))]
    md += ["", "Contact impedance x conductivity per electrode (mm): "
           + ", ".join(f"e{k} {1e3 * math.exp(v['value']):.3g}" + ("" if v["se"] is not None else " (n.d.)")
                       for k, v in enumerate(z, start=1)), "",
           "Derived, were the file's currents in mA (the unit and the conductivity only appear as a ratio): "
           f"conductivity {metrics['fitted']['derived']['conductivity_S_per_m_if_mA']['value']:.4g} S/m, electrode "
           f"height {metrics['fitted']['derived']['electrode_height_m']:.4g} m, metal's contact impedance "
           f"{metrics['fitted']['derived']['metal_contact_impedance_ohm_m2_if_mA']:.3g} ohm m^2.", "",
           "Not separable (directions the data do not determine): "
           + "; ".join(str(d["unknowns"]) for stage in metrics["not_separable"].values() for d in stage), "",
           "Correlated above 0.95: " + "; ".join(f"{c['unknowns'][0]} ~ {c['unknowns'][1]} ({c['correlation']})"
                                                 for stage in metrics["correlated"].values() for c in stage), ""]
    d = metrics.get("diagnosis")
    if d:
        md += ["## The gap", "", "Empty tank, held out by pattern:", "", "| candidate | held-out RMS | shrink |",
               "|---|---|---|"]
        md += [f"| {k} | {_pct(v['heldout_rms_rel'])} | {100 * v['shrink']:.0f} % |"
               for k, v in d["empty_tank_candidates"].items()]
        e = d.get("empty_tank_engine")
        if e:
            det = e["detection"]
            md += ["", f"The diagnosis engine (every fifth pattern held out; {e['noise_model']}; detection at a "
                       f"{100 * det['alpha']:.0f} % false-alarm rate): verdict **{e['verdict']}**, "
                       + (f"chosen {e['chosen']}" if e["chosen"] else f"nothing named (nearest {e['combination']})")
                       + f", held-out {_pct(e['gap_before'])} -> {_pct(e['gap_after'])}."]
            md += [f"- {name}: " + ", ".join(f"{p} {v:.4g} (95 % {lo:.3g} to {hi:.3g})" for p, v in ps.items()
                                            for lo, hi in [e["interval_95"][name][p]])
                   for name, ps in e["parameters"].items()]
        md += ["", "Tanks' change, held out by tank (median over tanks):", "", "| candidate | median | per tank |",
               "|---|---|---|"]
        md += [f"| {k} | {_pct(v['median'])} | " + ", ".join(f"{t} {_pct(x)}" for t, x in
                                                         v["heldout_rms_rel_by_tank"].items()) + " |"
               for k, v in d["tank_change_candidates"].items()]
        md += ["", "Worst channels before any effect: " + ", ".join(f"{w['channel']} ({_pct(w['rms_rel'])})"
                                                               for w in d["worst_channels"]), ""]
    md += [f"![{p.stem}]({p.name})" for p in figs]
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")
    return path
