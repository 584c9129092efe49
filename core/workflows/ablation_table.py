"""The ablation's tables: every variant × parameter source, mean ± std over seeds, and which
differences are beyond the noise (paired by seed; :mod:`..evaluate.seed_stats`)."""

from __future__ import annotations

from ..evaluate.seed_stats import format_difference, format_mean_std, paired_difference

SOURCE_LABELS = {"tracked": "tracked", "tracked_aligned": "tracked + the run's mean fine-tuning offset",
                 "smoothed": "smoothed (σ from training sequences)",
                 "method": "the method's image-assisted inference", "true": "true parameters (raw)",
                 "true_gauge": "true parameters in the avatar's gauge (the ceiling)"}
# The rungs every later variant is also set against, paired by seed and source: Freeze (the
# paper's baseline) and fine-tuning (what the paper's modules add over per-timestep fine-tuning).
REFERENCES = {"freeze": "Freeze", "finetune": "fine-tuning"}
REFERENCE_METRICS = (("psnr", 2), ("ssim", 4), ("lpips", 4))


def source_label(name: str) -> str:
    if name.startswith("fit_"):
        return f"test-time fitting, {name[4:]} steps"
    if name.startswith("refined_fit_"):
        return (f"multi-view refiner, 1 pass, then test-time fitting, {name[len('refined_fit_'):]} steps "
                "where training did not fit")
    if name.startswith("refined_"):
        passes = name[len("refined_"):]
        return f"multi-view refiner, {passes} pass{'' if passes == '1' else 'es'}"
    return SOURCE_LABELS.get(name, name)


def _values(entry: dict, *path) -> list:
    """One number per seed of a variant (None where a seed lacks it)."""
    out = []
    for seed_result in entry["seeds"].values():
        node = seed_result
        for key in path:
            node = node.get(key) if isinstance(node, dict) else None
        out.append(node)
    return out


def _sources(entry: dict, protocol: str) -> list[str]:
    names: list[str] = []
    for seed_result in entry["seeds"].values():
        for name in seed_result.get("protocols", {}).get(protocol, {}):
            if name not in names:
                names.append(name)
    return names


def _table(results: dict, protocol: str, columns: list[tuple[str, str, int]]) -> list[str]:
    variants = results["variants"]
    order = list(variants)
    references = [r for r in REFERENCES if r in variants]
    header = ["variant", "source", *[c[0] for c in columns], "Δ PSNR vs tracked", "Δ mesh mm vs tracked"]
    header += [f"Δ PSNR / SSIM / LPIPS vs {REFERENCES[r]} (same source)" for r in references]
    lines = ["| " + " | ".join(header) + " |", "|---|---|" + "---:|" * (len(header) - 2)]
    for name, entry in variants.items():
        for source in _sources(entry, protocol):
            cells = [entry["label"], source_label(source)]
            cells += [format_mean_std(_values(entry, "protocols", protocol, source, key), digits)
                      for _, key, digits in columns]
            for key, digits in (("psnr", 2), ("vertex_mm", 2)):
                if source == "tracked":
                    cells.append("")
                    continue
                diff = paired_difference(_values(entry, "protocols", protocol, source, key),
                                         _values(entry, "protocols", protocol, "tracked", key))
                cells.append(format_difference(diff, digits))
            for reference in references:  # the later rungs only
                if order.index(name) <= order.index(reference):
                    cells.append("")
                    continue
                cells.append(" / ".join(
                    format_difference(paired_difference(_values(entry, "protocols", protocol, source, key),
                                                        _values(variants[reference], "protocols", protocol, source,
                                                                key)), digits)
                    for key, digits in REFERENCE_METRICS))
            lines.append("| " + " | ".join(cells) + " |")
    return lines


FREE_COLUMNS = [("expr vertex mm", "expr_vertex_mm", 2), ("mesh vertex mm", "vertex_mm", 2),
                ("expr vertex mm, gauge", "expr_vertex_mm_gauge", 2), ("mesh vertex mm, gauge", "vertex_mm_gauge", 2),
                ("expr RMSE", "expr_rmse", 3), ("PSNR", "psnr", 2), ("SSIM", "ssim", 4), ("LPIPS", "lpips", 4),
                ("s / frame", "frame_s", 2)]
NOVEL_COLUMNS = [("mesh vertex mm", "vertex_mm", 2), ("mesh vertex mm, gauge", "vertex_mm_gauge", 2), ("PSNR", "psnr", 2), ("SSIM", "ssim", 4),
                 ("LPIPS", "lpips", 4), ("s / frame", "frame_s", 2)]


def markdown(results: dict) -> str:
    """Three tables (unseen frames, held-out camera, training) and how to read them."""
    seeds = "; ".join(f"{e['label']} {', '.join(e['seeds'])}" for e in results["variants"].values())
    lines = [f"Seeds: {seeds}. Cells: mean ± std over seeds. Δ: paired by seed; "
             "* beyond noise (paired t-test, 5 %), (n.s.) within it, (n/a) the test cannot tell (one seed, or no "
             "spread between seeds).", ""]
    if results.get("split", "test") == "validation":
        lines += ["**Validation frames** (self-reenactment of the validation sequence, every camera; where "
                  "settings are chosen: the test frames are scored once, without --split validation):", ""]
    else:
        lines += ["**Unseen frames** (self-reenactment of the held-out sequence, every camera; scored view never "
                  "a source's input):", ""]
    lines += _table(results, "self_reenactment", FREE_COLUMNS)
    if results.get("split", "test") == "test":
        lines += ["", "**Held-out camera** (novel view at the training timesteps):", ""]
        lines += _table(results, "novel_view", NOVEL_COLUMNS)
    lines += ["", "**Training timesteps** (the run's own parameters against the truth; camera error of the "
              "calibration and of refined cameras where a run writes them):", "",
              "| variant | expr RMSE tracked → trained | expr vertex mm tracked → trained "
              "| mesh vertex mm tracked → trained | camera error ° calibrated → refined | it/s | Gaussians |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for entry in results["variants"].values():
        cells = [entry["label"]]
        for key, digits in (("expr_rmse", 3), ("expr_vertex_mm", 2), ("vertex_mm", 2)):
            before = format_mean_std(_values(entry, "training_expression", key + "_tracked"), digits)
            after = format_mean_std(_values(entry, "training_expression", key + "_corrected"), digits)
            cells.append(f"{before} → {after}")
        calibrated = format_mean_std(_values(entry, "cameras", "calibrated", "rotation_deg"), 3)
        refined = format_mean_std(_values(entry, "cameras", "refined", "rotation_deg"), 3)
        cells.append(f"{calibrated} → {refined}")
        cells.append(format_mean_std(_values(entry, "train", "it_s"), 1))
        cells.append(format_mean_std(_values(entry, "train", "gaussians"), 0))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
