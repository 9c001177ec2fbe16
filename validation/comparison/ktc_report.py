"""The KTC study's report: ``report.md``, the figures, and the summary printed beside the goals."""
from __future__ import annotations

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
                     f"{_pct(v['heldout_rms_rel'])} (floor {_pct(v['difference_floor_rel'])}, drift "
                     f"{100 * v['drift']:+.2f} %)")
    for k, v in m.get("predicted", {}).items():
        if "error" in v:
            lines.append(f"predicted {k}: not modelled ({v['error']})")
            continue
        lines.append(f"predicted {k}: change {_pct(v['difference_rms_rel'])} of itself (floor "
                     f"{_pct(v['difference_floor_rel'])}), total {_pct(v['total_rms_rel'])}")
    s = m.get("predicted_summary")
    if s:
        lines.append(f"predicted changes: median {_pct(s['difference_rms_rel_median'])}, max "
                     f"{_pct(s['difference_rms_rel_max'])} over {s['files']} files (goal: median <= 15 %, none > 35 %)")
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
    md += [f"![{p.stem}]({p.name})" for p in figs]
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")
    return path
