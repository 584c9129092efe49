"""The parameter-source table of docs/results.md from ``bench refiner`` reports of several runs:
one block per subject (mean ± std over its runs), and one over every subject no setting was
chosen on, pooled. Images and parameters side by side: PSNR, the mesh and expression errors against
the raw truth and in the avatar's gauge (:func:`mogaface.core.evaluate.expression_error.truth_gauge`),
seconds per frame, and the refiner's time against fitting at equal quality.
"""

from __future__ import annotations

# the subject every setting of the refiner and fitting was chosen on (its validation frames,
# ``bench refiner_search``); the pooled block leaves it out
TUNING_SUBJECT = 0
LABELS = {"tracked": "tracked", "tracked_aligned": "tracked + the run's mean fine-tuning offset (the start)",
          "refined_1": "**refiner, 1 pass** (the default)", "refined_3": "refiner, 3 passes",
          "true": "true parameters (raw)", "true_gauge": "true parameters in the avatar's gauge (the ceiling)"}
# (heading, where in a report (None: the source's name), digits)
COLUMNS = (("PSNR", ("psnr_db", None), 2), ("mesh mm", ("parameter_errors_mm", None, "vertex_mm"), 2),
           ("expr mm", ("parameter_errors_mm", None, "expr_vertex_mm"), 2),
           ("mesh mm, gauge", ("parameter_errors_mm", None, "vertex_mm_gauge"), 2),
           ("expr mm, gauge", ("parameter_errors_mm", None, "expr_vertex_mm_gauge"), 2),
           ("s / frame", ("seconds_per_frame", None), 2))


def label(name: str) -> str:
    if name.startswith("refined_fit_"):
        return f"refiner 1 pass, then {name[len('refined_fit_'):]} fitting steps"
    if name.startswith("fit_"):
        return f"test-time fitting, {name[4:]} steps"
    return LABELS.get(name, name)


def _value(report: dict, path: tuple, source: str):
    node = report
    for key in path:
        node = node.get(source if key is None else key) if isinstance(node, dict) else None
    return node


def _group_name(report: dict) -> str:
    subject = report.get("subject") or {}
    if "subject" in subject:
        return f"subject {subject['subject']} (tracker draw {subject.get('seed', '?')})"
    return report.get("capture", "?")


def _block(title: str, reports: list[dict]) -> list[str]:
    from mogaface.core.evaluate.seed_stats import format_difference, format_mean_std, paired_difference

    names: list[str] = []
    for report in reports:
        names += [n for n in report["psnr_db"] if n not in names]
    frames = sorted({report["frames"] for report in reports})
    lines = [f"**{title}**: {len(reports)} run{'s' if len(reports) != 1 else ''}, "
             f"{'/'.join(map(str, frames))} frames each ({reports[0]['scored'].get('label', '?')}, "
             f"{reports[0]['split']} split); load {_loads(reports)}.", "",
             "| source | " + " | ".join(c[0] for c in COLUMNS) + " | PSNR Δ vs the start |",
             "|---|" + "---:|" * (len(COLUMNS) + 1)]
    for name in names:
        cells = [label(name)] + [format_mean_std([_value(r, path, name) for r in reports], digits)
                                 for _, path, digits in COLUMNS]
        start = "tracked_aligned" if "tracked_aligned" in names else "tracked"
        cells.append("" if name in (start, "tracked") else format_difference(paired_difference(
            [_value(r, ("psnr_db", None), name) for r in reports], [_value(r, ("psnr_db", None), start) for r in reports]), 2))
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "| refiner | matching fitting length (interpolated) | fitting's time over the refiner's there "
                  "| PSNR Δ refiner − fitting 30 steps |", "|---|---:|---:|---:|"]
    for source in sorted({k for r in reports for k in r.get("equal_quality", {})}):
        entries = [r["equal_quality"].get(source, {}) for r in reports]
        statuses = sorted({e.get("status", "?") for e in entries})
        fit30 = "fit_30" if any("fit_30" in r["psnr_db"] for r in reports) else None
        diff = (format_difference(paired_difference([_value(r, ("psnr_db", None), source) for r in reports],
                                                    [_value(r, ("psnr_db", None), fit30) for r in reports]), 2)
                if fit30 else "–")
        lines.append(f"| {label(source)} | {format_mean_std([e.get('fit_steps') for e in entries], 1)} "
                     f"({', '.join(statuses)}) | {format_mean_std([e.get('fitting_time_over_refiner') for e in entries], 1)}× "
                     f"| {diff} |")
    return lines + [""]


def _loads(reports: list[dict]) -> str:
    values = [x for r in reports for x in (r.get("load_average_before", [None])[0],
                                            r.get("load_average_after", [None])[0]) if x is not None]
    return f"{min(values):.1f}–{max(values):.1f}" if values else "not recorded"


def summary_table(reports: list[dict]) -> dict:
    """``{"groups": {name: runs}, "markdown": the table}``: a block per subject, then the pooled
    subjects other than :data:`TUNING_SUBJECT`."""
    groups: dict[str, list[dict]] = {}
    for report in reports:
        groups.setdefault(_group_name(report), []).append(report)
    lines = []
    for name, members in groups.items():
        lines += _block(name[:1].upper() + name[1:], members)
    unseen = [r for r in reports if (r.get("subject") or {}).get("subject", TUNING_SUBJECT) != TUNING_SUBJECT]
    if len({_group_name(r) for r in unseen}) > 1:
        lines += _block(f"Subjects no setting was chosen on, pooled (not subject {TUNING_SUBJECT})", unseen)
    return {"groups": {name: [r["run"] for r in members] for name, members in groups.items()},
            "markdown": "\n".join(lines)}
