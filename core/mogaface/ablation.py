"""The ablation ladder of the paper's tables 3 and 4 on one capture: train, score, tabulate, show.

Every variant starts from the same settings and seed and differs only in its ``[mogaface]`` and ``[flame]``
section. Scores: novel view (training timestamps, held-out camera; corrections from the bank or
the training views), self-reenactment both parameter-driven and image-assisted (other views of
the timestamp, scored view left out), and the expression error against the synthetic truth.
"""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np

from ..train.config import FULL_METHOD


def _variant(mode: str, bank: bool = False, texture: bool = False, finetune: bool = True) -> dict:
    return {"mogaface": {"mode": mode, "bank": bank, "texture": texture, "centring_weight": 0.0},
            "flame": {"finetune": finetune}}


# The settings of each variant over the common preset. Every variant but Freeze fine-tunes the
# per-timestamp FLAME parameters as the paper's training does (at the rates of the preset); "finetune"
# does that alone, so the gain of the modules over it can be told apart from the fine-tuning's own.
# "full_prior" is the full method with our zero-mean prior on the correction: what the MoGaFace
# presets train.
LADDER: dict[str, dict] = {
    "freeze": _variant("off", finetune=False),
    "finetune": _variant("off"),
    "single": _variant("single"),
    "multi": _variant("multi"),
    "multi_bank": _variant("multi", bank=True),
    "multi_texture": _variant("multi", texture=True),
    "full": _variant("multi", bank=True, texture=True),
    "full_prior": {"mogaface": dict(FULL_METHOD), "flame": {"finetune": True}},
}
LABELS = {"freeze": "Freeze", "finetune": "Freeze + FLAME fine-tuning", "single": "Single-view",
          "multi": "Multi-view (O)", "multi_bank": "Multi-view + bank (M)", "multi_texture": "Multi-view + texture (T)",
          "full": "Full (multi + bank + texture)", "full_prior": "Full + zero-mean prior (the presets)"}
METRICS = ("psnr", "ssim", "lpips")


def _merge(a: dict, b: dict) -> dict:
    out = {k: dict(v) for k, v in a.items()}
    for section, values in b.items():
        out.setdefault(section, {}).update(values)
    return out


def _complete(run_dir: pathlib.Path) -> bool:
    path = run_dir / "run.json"
    return path.exists() and bool(json.loads(path.read_text(encoding="utf-8")).get("complete"))


def train_variant(capture, run_dir: pathlib.Path, name: str, preset, config_path, overrides, progress) -> None:
    """Train one variant (reusing a complete run, resuming an interrupted one)."""
    from ..train import config as config_module
    from ..train.checkpoint import latest_checkpoint
    from ..train.trainer import Trainer

    if _complete(run_dir):
        return
    resume = latest_checkpoint(run_dir / "checkpoints") is not None
    config = config_module.resolve(preset, config_path, _merge(overrides or {}, LADDER[name]))
    listeners = []
    if progress:
        from ..progress import ProgressBar

        state = {}

        def show(event):
            if event["event"] in ("start", "resume"):
                state["bar"] = ProgressBar(event["steps"], f"train {name}")
                state["bar"].update(event["step"])
            elif event["event"] == "iter" and "bar" in state:
                state["bar"].update(event["step"] - state["bar"].done, f"psnr {event['psnr']:.2f}")

        listeners.append(show)
    trainer = Trainer(capture, run_dir, None if resume else config, resume=resume, listeners=listeners)
    try:
        trainer.run()
    finally:
        trainer.events.close()


def sources(run_dir):
    """``(avatar, parameter-driven source, image-assisted source)`` of a run."""
    from ..evaluate.mogaface_source import MoGaFaceParams
    from ..evaluate.protocols import TrackedParams
    from ..evaluate.run_folder import RunFolder
    from .avatar import ModulatedAvatar, load_run_avatar

    run = RunFolder(run_dir)
    capture = run.open_capture()
    avatar = load_run_avatar(run_dir)
    if not isinstance(avatar, ModulatedAvatar):
        tracked = TrackedParams(capture, run)
        return avatar, tracked, tracked
    return avatar, MoGaFaceParams(capture, run, avatar.model, False), MoGaFaceParams(capture, run, avatar.model, True)


def _means(result: dict, protocol: str) -> dict:
    summary = result["protocols"][protocol]
    return {k: summary.get(k) for k in ("frames", *METRICS) if k in summary}


def score_variant(run_dir: pathlib.Path, max_frames, lpips: bool) -> dict:
    from ..evaluate.expression_error import expression_errors
    from ..evaluate.protocols import evaluate_run

    avatar, by_params, by_images = sources(run_dir)
    out = {}
    common = dict(max_frames=max_frames, lpips=lpips, avatar=avatar, comparisons=2)
    novel = evaluate_run(run_dir, ["novel_view"], out_dir=run_dir / "eval" / "novel_view", source=by_images, **common)
    out["novel_view"] = _means(novel, "novel_view")
    params = evaluate_run(run_dir, ["self_reenactment"], out_dir=run_dir / "eval" / "self_reenactment_params",
                          source=by_params, **common)
    out["self_reenactment_params"] = _means(params, "self_reenactment")
    if by_images is by_params:
        out["self_reenactment_images"] = dict(out["self_reenactment_params"])
    else:
        images = evaluate_run(run_dir, ["self_reenactment"], out_dir=run_dir / "eval" / "self_reenactment_images",
                              source=by_images, **common)
        out["self_reenactment_images"] = _means(images, "self_reenactment")
    try:
        out["expression"] = expression_errors(run_dir)
    except Exception as error:  # a capture without truth: report what is missing
        out["expression"] = {"error": str(error)}
    return out


def _train_summary(run_dir: pathlib.Path) -> dict:
    info = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
    steps, wall = info.get("final_step"), info.get("wall_time_s")
    return {"steps": steps, "wall_time_s": wall, "it_s": round(steps / wall, 3) if steps and wall else None,
            "gaussians": info.get("gaussians")}


def _fmt(value, digits=2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def markdown(results: dict) -> str:
    """The results table: one row per variant."""
    lines = [
        "| variant | novel view PSNR | SSIM | LPIPS | self-reen. (params) PSNR | SSIM | LPIPS "
        "| self-reen. (images) PSNR | SSIM | LPIPS | expr RMSE tracked → corrected "
        "| expr vertex error mm tracked → corrected | mesh vertex error mm tracked → corrected | it/s |",
        "|---|" + "---|" * 13,
    ]
    for name, entry in results["variants"].items():
        cells = [LABELS.get(name, name)]
        for key in ("novel_view", "self_reenactment_params", "self_reenactment_images"):
            m = entry.get(key, {})
            cells += [_fmt(m.get("psnr")), _fmt(m.get("ssim"), 4), _fmt(m.get("lpips"), 4)]
        e = entry.get("expression", {})
        cells.append(f"{_fmt(e.get('expr_rmse_tracked'), 3)} → {_fmt(e.get('expr_rmse_corrected'), 3)}")
        for key in ("expr_vertex_mm", "vertex_mm"):
            cells.append(f"{_fmt(e.get(key + '_tracked'), 2)} → {_fmt(e.get(key + '_corrected'), 2)}")
        cells.append(_fmt(entry.get("train", {}).get("it_s"), 1))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_figure(path: pathlib.Path, run_dirs: dict[str, pathlib.Path]) -> None:
    """One novel-view and one self-reenactment frame (image-assisted): every variant, then the truth."""
    from PIL import Image, ImageDraw

    from ..evaluate.protocols import protocol_frames, render_frame, target_image
    from ..evaluate.run_folder import RunFolder
    from ..io.atomic import atomic_path

    first = RunFolder(next(iter(run_dirs.values())))
    capture = first.open_capture()
    picks = []
    for protocol in ("novel_view", "self_reenactment"):
        frames = protocol_frames(capture, protocol)
        picks.append(frames[len(frames) // 2])
    rows = []
    for frame in picks:
        tiles = []
        for run_dir in run_dirs.values():
            avatar, _, by_images = sources(run_dir)
            params = by_images.params_for(frame, exclude_view=frame.camera_id)
            rgb, _ = render_frame(avatar, params, capture.camera(frame), first.background)
            tiles.append(rgb)
        tiles.append(target_image(capture, frame, first.background, first.background))
        rows.append(np.concatenate(tiles, axis=1))
    grid = (np.clip(np.concatenate(rows, axis=0), 0, 1) * 255 + 0.5).astype(np.uint8)
    header = 18
    width = grid.shape[1] // (len(run_dirs) + 1)
    canvas = Image.new("RGB", (grid.shape[1], grid.shape[0] + header), "white")
    canvas.paste(Image.fromarray(grid), (0, header))
    draw = ImageDraw.Draw(canvas)
    for i, name in enumerate([*run_dirs, "truth"]):
        draw.text((i * width + 3, 3), name, fill="black")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        canvas.save(tmp, format="PNG")


def run_ablation(capture, out, variants, *, preset="mogaface-ablation", config_path=None, overrides=None,
                 max_frames=None, lpips=True, progress=True) -> dict:
    """Train and score ``variants`` of :data:`LADDER`; write results.json, results.md, figure.png."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = {"capture": str(pathlib.Path(capture).resolve()), "preset": preset,
               "config": None if config_path is None else str(config_path), "overrides": overrides or {},
               "max_frames": max_frames, "cpu_count": os.cpu_count(), "variants": {}}
    scored: dict[str, dict] = {}
    for name in variants:
        run_dir = out / "runs" / name
        train_variant(capture, run_dir, name, preset, config_path, overrides, progress)
        entry = {"label": LABELS[name], "settings": LADDER[name], "train": _train_summary(run_dir)}
        entry.update(score_variant(run_dir, max_frames, lpips))
        scored[name] = entry
        _write_results(out, results, scored)
        if progress:
            print(f"[ablate] {name}: {json.dumps({k: entry[k] for k in ('novel_view', 'expression')})}", flush=True)
    results = _write_results(out, results, scored)
    run_dirs = {name: out / "runs" / name for name in results["variants"]}
    write_figure(out / "figure.png", run_dirs)
    return results


def _write_results(out: pathlib.Path, results: dict, scored: dict) -> dict:
    """results.json and results.md with this call's variants and, in ladder order, the complete
    variants an earlier call in the same folder scored (so parts of the ladder can run separately)."""
    from ..io.atomic import write_json, write_text

    earlier = {}
    path = out / "results.json"
    if path.exists():
        try:
            earlier = json.loads(path.read_text(encoding="utf-8")).get("variants", {})
        except (OSError, ValueError):
            earlier = {}
    merged = {**earlier, **scored}
    results = {**results, "variants": {name: merged[name] for name in LADDER
                                       if name in merged and _complete(out / "runs" / name)}}
    write_json(path, results)
    write_text(out / "results.md", markdown(results))
    return results
