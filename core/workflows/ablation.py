"""The ablation ladder of the paper's tables 3 and 4 on one capture: train, score, tabulate, show.

Every variant starts from the same settings and differs only in its ``[mogaface]`` and ``[flame]``
section; each is trained once per seed (``OUT/runs/NAME/seedS``). Each run is scored with every
parameter source of :mod:`..evaluate.benchmark` (tracked, smoothed, test-time fitted, the method's
image-assisted inference, the truth) on the held-out sequence (unseen frames) and the held-out
camera, and its training timesteps' expression error against the synthetic truth. The tables give
mean ± std over seeds and mark the differences beyond noise (:mod:`.ablation_table`).
"""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np

from ..run.folder import is_complete
from ..run.names import RUN_FILE
from ..train.presets import FULL_METHOD


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


def merge_sections(a: dict, b: dict) -> dict:
    """``a``'s ``{section: {key: value}}`` settings updated by ``b``'s, section by section."""
    out = {k: dict(v) for k, v in a.items()}
    for section, values in b.items():
        out.setdefault(section, {}).update(values)
    return out


def train_variant(capture, run_dir: pathlib.Path, name: str, preset, config_path, overrides, progress) -> None:
    """Train one variant (reusing a complete run, resuming an interrupted one)."""
    from ..train import config as config_module
    from ..train.checkpoint import has_checkpoint
    from ..train.trainer import Trainer

    if is_complete(run_dir):
        return
    resume = has_checkpoint(run_dir)
    config = config_module.resolve(preset, config_path, merge_sections(overrides or {}, LADDER[name]))
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


# a run's scores, reused while the run, the scoring options and the scoring code are unchanged
SCORES_FILE = "ablation_scores.json"


def split_name(name: str, split: str) -> str:
    """A file of the test frames keeps its name; one of the validation frames gets ``_validation``
    before the suffix (``results_validation.json``), so the two never overwrite or merge."""
    if split == "test":
        return name
    stem, dot, suffix = name.partition(".")
    return f"{stem}_{split}{dot}{suffix}"


def run_folder(out: pathlib.Path, name: str, seed: int) -> pathlib.Path:
    return out / "runs" / name / f"seed{seed}"


def image_source(run_dir):
    """``(avatar, source)``: the run's own inference, image-assisted where it has modules."""
    from ..correction.avatar import ModulatedAvatar
    from ..evaluate.sources.corrected import MoGaFaceParams
    from ..evaluate.sources.tracked import TrackedParams
    from ..run.folder import RunFolder

    run = RunFolder(run_dir)
    capture = run.open_capture()
    avatar = run.load_avatar()
    if not isinstance(avatar, ModulatedAvatar):
        return avatar, TrackedParams(capture, run)
    return avatar, MoGaFaceParams(capture, run, avatar.model, True)


def score_variant(run_dir: pathlib.Path, max_frames, lpips: bool, fit_steps, split: str = "test") -> dict:
    """Every parameter source on both protocols (:mod:`..evaluate.benchmark`), and the expression
    error of the training timesteps (tracked → as training left them). Kept in the run folder, so
    scoring several runs can go on side by side and the table be written again without rescoring;
    kept scores are used again only under the same options and the same scoring code (a hash of its
    files, :func:`..evaluate.benchmark.scoring_code_hash`). ``split``: the test or the validation
    frames, each kept in a file of its own (:func:`split_name`)."""
    from ..errors import InputError
    from ..evaluate.benchmark import benchmark_run, scoring_code_hash
    from ..evaluate.expression_error import expression_errors
    from ..evaluate.sources.fitted import fitting_settings
    from ..io.atomic import write_json
    from ..refiner.files import REFINER_FILE
    from ..run.names import REFINED_CAMERAS_FILE

    def changed(name):  # a refiner trained later, refined cameras written later: score again
        path = run_dir / name
        return path.stat().st_mtime_ns if path.exists() else None

    options = {"max_frames": max_frames, "lpips": lpips, "fit_steps": list(fit_steps), "fitting": fitting_settings(),
               "refiner": changed(REFINER_FILE), "refined_cameras": changed(REFINED_CAMERAS_FILE),
               "scoring_code": scoring_code_hash(), "split": split}
    cached = run_dir / split_name(SCORES_FILE, split)
    if cached.exists() and cached.stat().st_mtime >= (run_dir / RUN_FILE).stat().st_mtime:
        try:
            earlier = json.loads(cached.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            earlier = {}
        if earlier.get("options") == options:
            return earlier["scores"]
    out = benchmark_run(run_dir, max_frames=max_frames, lpips=lpips, fit_steps=fit_steps, split=split)
    try:
        out["training_expression"] = expression_errors(run_dir)
    except InputError as error:  # a capture without truth: report what is missing
        out["training_expression"] = {"error": str(error)}
    write_json(cached, {"options": options, "scores": out})
    return out


def _train_summary(run_dir: pathlib.Path) -> dict:
    info = json.loads((run_dir / RUN_FILE).read_text(encoding="utf-8"))
    steps, wall = info.get("final_step"), info.get("wall_time_s")
    return {"steps": steps, "wall_time_s": wall, "it_s": round(steps / wall, 3) if steps and wall else None,
            "gaussians": info.get("gaussians")}


def write_figure(path: pathlib.Path, run_dirs: dict[str, pathlib.Path], split: str = "test") -> None:
    """One novel-view and one self-reenactment frame (image-assisted): every variant, then the truth
    (the validation frames: self-reenactment only)."""
    from PIL import Image, ImageDraw

    from ..avatar.avatar import render_frame
    from ..data.target import target_image
    from ..evaluate.protocols import protocol_frames
    from ..io.atomic import atomic_path
    from ..run.folder import RunFolder

    first = RunFolder(next(iter(run_dirs.values())))
    capture = first.open_capture()
    picks = []
    for protocol in ("novel_view", "self_reenactment") if split == "test" else ("self_reenactment",):
        frames = protocol_frames(capture, protocol, split=split)
        picks.append(frames[len(frames) // 2])
    rows = []
    for frame in picks:
        tiles = []
        for run_dir in run_dirs.values():
            avatar, by_images = image_source(run_dir)
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


def run_ablation(capture, out, variants, *, seeds=(0,), preset="mogaface-ablation", config_path=None, overrides=None,
                 max_frames=None, lpips=True, fit_steps=None, progress=True, split="test") -> dict:
    """Train and score ``variants`` of :data:`LADDER` with every seed; write results.json,
    results.md (mean ± std over seeds, differences beyond noise marked) and figure.png (first seed).
    ``split="validation"`` scores the validation sequence instead, into ``results_validation.json``,
    ``.md`` and ``figure_validation.png``: where settings are chosen before the test frames are
    scored once."""
    from ..evaluate.benchmark import FIT_STEPS

    fit_steps = FIT_STEPS if fit_steps is None else tuple(fit_steps)
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = {"capture": str(pathlib.Path(capture).resolve()), "preset": preset,
               "config": None if config_path is None else str(config_path), "overrides": overrides or {},
               "max_frames": max_frames, "fit_steps": list(fit_steps), "split": split, "cpu_count": os.cpu_count(),
               "load_average": _load_average(), "variants": {}}
    scored: dict[str, dict] = {}
    for seed in seeds:
        for name in variants:
            run_dir = run_folder(out, name, seed)
            seeded = merge_sections(overrides or {}, {"train": {"seed": int(seed)}})
            train_variant(capture, run_dir, name, preset, config_path, seeded, progress)
            entry = {"train": _train_summary(run_dir), **score_variant(run_dir, max_frames, lpips, fit_steps, split)}
            scored.setdefault(name, {})[str(seed)] = entry
            results = _write_results(out, results, scored)
            if progress:
                free = entry["protocols"].get("self_reenactment", {})
                print(f"[ablate] {name} seed {seed}: " + json.dumps({k: v.get("psnr") for k, v in free.items()}), flush=True)
    first = str(seeds[0])
    write_figure(out / split_name("figure.png", split), {name: run_folder(out, name, first)
                                                         for name in results["variants"]
                                                         if first in results["variants"][name]["seeds"]}, split)
    return results


def _load_average() -> list[float] | None:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def _write_results(out: pathlib.Path, results: dict, scored: dict) -> dict:
    """results.json and results.md with this call's runs and, in ladder order, the complete runs an
    earlier call in the same folder scored (so parts of the ladder and seeds can run separately)."""
    from ..io.atomic import write_json, write_text
    from .ablation_table import markdown

    earlier = {}
    split = results["split"]
    path = out / split_name("results.json", split)
    if path.exists():
        try:
            earlier = json.loads(path.read_text(encoding="utf-8")).get("variants", {})
        except (OSError, ValueError):
            earlier = {}
    merged: dict[str, dict] = {}
    for name in LADDER:
        seeds = {**earlier.get(name, {}).get("seeds", {}), **scored.get(name, {})}
        seeds = {s: v for s, v in sorted(seeds.items(), key=lambda kv: int(kv[0]))
                 if is_complete(run_folder(out, name, s))}
        if seeds:
            merged[name] = {"label": LABELS[name], "settings": LADDER[name], "seeds": seeds}
    results = {**results, "variants": merged}
    write_json(path, results)
    write_text(out / split_name("results.md", split), markdown(results))
    return results
