"""Benchmark: avatars trained on tracked phone clips against ones trained on the clips' truth.

The paper's camera-free table, measured here. For each video clip of a ``bench track`` split
(made and tracked there first): a second capture is written with the same images, masks and
splits but the truth's cameras and FLAME parameters (``truth_capture``). Both are trained alike,
with and without the method's corrections (``demo`` and ``mogaface-demo``, each its own length
unless ``steps``), and drawn at the truth's novel cameras, which the footage never saw, at the
frames it rendered them. The truth-trained avatar is drawn at those cameras as they are; the
tracked one at those cameras moved, per frame, from the true head onto the tracked head, as the
aligned novel-view protocol moves a held-out camera, in two ways (:func:`novel_psnr`): by the
heads' poses (``rigid``), and by the similarity between the meshes (``similarity``), which also
forgives the head's size: no picture tells a larger head farther away from a smaller one nearer,
and the aligned mesh error forgives it alike. PSNR against the truth's renders (white
background). Each avatar is trained with ``seeds`` training seeds (default one: seed 0); the
gaps are averaged over the clips and seeds. Trained avatars are kept and reused (each step count
and seed its own); a tracked one is trained again when its clip was tracked again since.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil

import numpy as np

PRESETS = ("demo", "mogaface-demo")


def truth_capture(clip: pathlib.Path, tracked: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
    """``tracked``'s images, masks and splits with the truth's cameras and parameters."""
    from mogaface.core.data import layout
    from mogaface.core.data.camera_file import read_cameras
    from mogaface.core.data.capture import Capture
    from mogaface.core.data.writer import CaptureWriter
    from mogaface.core.flame.model import FlameModel
    from mogaface.core.io.npz import load_npz

    if (out / "transforms_train.json").is_file():
        return out
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    report = json.loads((tracked / "tracking.json").read_text())
    truth = clip / "truth"
    cameras = read_cameras(truth / "cameras.json")
    shutil.copyfile(truth / "head.pkl", out / "head.pkl")
    capture = Capture.open(tracked)
    with CaptureWriter(out, n_vertices=FlameModel.load(out / "head.pkl").n_vertices) as writer:
        for split in ("train", "test"):
            for frame in capture.frames(split):
                t = frame.timestep_index
                index = report["input_frames"][t]
                true = cameras[f"{index:05d}"]
                camera = dataclasses.replace(true.scaled(capture.camera(frame).width / true.width), camera_id="cam00")
                for name in (layout.image_path(t, 0), layout.mask_path(t, 0)):
                    (out / name).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(tracked / name, out / name)
                writer.write_flame_params(t, load_npz(truth / "flame_param" / f"{index:05d}.npz"))
                writer.record_frame(t, camera, split=split, camera_index=0)
    return out


MOVES = ("rigid", "similarity")  # how the truth's novel cameras are moved onto the tracked head


def novel_psnr(run: pathlib.Path, clip: pathlib.Path, tracked_report: dict, move: str | None) -> dict:
    """PSNR of ``run``'s avatar at the truth's novel cameras: as they are (``move`` None), or moved
    onto the tracked head, per frame, by the head's pose (``"rigid"``: the two heads' root frames)
    or by the similarity that best carries the tracked mesh onto the true one (``"similarity"``:
    also forgives the head's size, which no picture tells, as the aligned mesh error does)."""
    import torch

    from mogaface.core.data.camera_file import read_cameras
    from mogaface.core.evaluate.track_error import camera_onto, head_to_world, similarity, vertices_and_joints
    from mogaface.core.flame.model import FlameModel
    from mogaface.core.io.image import read_image
    from mogaface.core.io.npz import load_npz
    from mogaface.core.metrics import images as metrics
    from mogaface.core.run.folder import RunFolder

    truth = clip / "truth"
    info = json.loads((truth / "footage.json").read_text())["novel_views"]
    novel = read_cameras(truth / info["cameras"])
    avatar = RunFolder(run).load_avatar()
    true_model = FlameModel.load(truth / "head.pkl", dtype=torch.float64)
    fit_model = FlameModel.load(run / "head.pkl", dtype=torch.float64) if move else None
    index_of = {index: t for t, index in enumerate(tracked_report["input_frames"])}
    scores = []
    for frame in info["frames"]:
        t = index_of.get(frame)
        params_file = run / "flame_param" / f"{t:05d}.npz" if t is not None else None
        if params_file is None or not params_file.is_file():
            continue
        params = load_npz(params_file)
        onto = (1.0, np.eye(3), np.zeros(3))
        if move:
            true_params = load_npz(truth / "flame_param" / f"{frame:05d}.npz")
            true_vertices, true_joints = vertices_and_joints(true_model, true_params, True)
            fit_vertices, fit_joints = vertices_and_joints(fit_model, params, True)
            if move == "similarity":
                onto = similarity(fit_vertices, true_vertices)
            else:  # the tracked head's frame → the true head's frame
                shift = head_to_world(true_params, true_joints) @ np.linalg.inv(head_to_world(params, fit_joints))
                onto = (1.0, shift[:3, :3], shift[:3, 3])
        torch_params = {k: torch.as_tensor(np.asarray(v, np.float32).reshape(1, -1)) for k, v in params.items()
                        if k != "static_offset"}
        for camera_id, camera in novel.items():
            with torch.no_grad():
                rendered = avatar.render(torch_params, camera_onto(camera, *onto), (1.0, 1.0, 1.0))
            target = read_image(truth / info["images"].format(frame=frame, camera=camera_id))[..., :3]
            scores.append(metrics.psnr(rendered.rgb.clamp(0, 1).numpy(), target))
    return {"views": len(scores), "psnr": round(float(np.mean(scores)), 3) if scores else None}


def _trained_after(avatar: pathlib.Path, tracking: pathlib.Path) -> bool:
    """Whether ``avatar`` exists and was trained after its capture was tracked (the truth's capture
    has no ``tracking`` file: its avatar never goes stale)."""
    return avatar.is_file() and (not tracking.is_file() or avatar.stat().st_mtime > tracking.stat().st_mtime)


def clip_avatars(base: pathlib.Path, kind: str, seed: int, threads: int, steps: int | None,
                 training_seed: int = 0) -> dict:
    """One clip's avatars (trained unless kept) and their novel-view scores: ``{"steps", "psnr", "gaps"}``."""
    from mogaface.core.train import config as C
    from mogaface.core.train.trainer import Trainer

    clip, tracked = base / f"{kind}_{seed}", base / "tracked" / f"{kind}_{seed}"
    report = json.loads((tracked / "tracking.json").read_text())
    truth_cap = truth_capture(clip, tracked, base / "truth_capture" / f"{kind}_{seed}")
    psnr, lengths = {}, {}
    for preset in PRESETS:
        train = {"threads": threads, "seed": training_seed, **({"steps": steps} if steps else {})}
        config = C.resolve(preset=preset, overrides={"train": train, "eval": {"at_end": False}})
        lengths[preset] = config.train.steps
        folder = f"steps{config.train.steps}" + (f"_seed{training_seed}" if training_seed else "")
        for name, capture in (("tracked", tracked), ("truth", truth_cap)):
            run_dir = base / "avatars" / f"{kind}_{seed}_{name}_{preset}" / folder
            if not _trained_after(run_dir / "avatar.pt", capture / "tracking.json"):
                shutil.rmtree(run_dir, ignore_errors=True)
                Trainer(capture, run_dir, config).run()
            if name == "truth":
                psnr[f"{preset} truth"] = novel_psnr(run_dir, clip, report, move=None)
            else:
                for move in MOVES:
                    psnr[f"{preset} tracked, {move}"] = novel_psnr(run_dir, clip, report, move=move)
    gaps = {move: {preset: round(psnr[f"{preset} truth"]["psnr"] - psnr[f"{preset} tracked, {move}"]["psnr"], 3)
                   for preset in PRESETS} for move in MOVES}
    return {"steps": lengths, "psnr": psnr, "gaps": gaps}


def run(threads: int = 2, quick: bool = False, work: str | None = None, split: str | None = None,
        steps: int | None = None, seeds: int | None = None) -> dict:
    from .track import CLIPS

    base = pathlib.Path(work or "out/bench_track") / ("quick" if quick else "full")
    split = split or "test"
    clips = CLIPS[split]
    for kind, seed in clips:
        if not (tracked := base / "tracked" / f"{kind}_{seed}" / "tracking.json").is_file():
            raise SystemExit(f"error: {tracked.parent}: run `bench track --split {split}` first")
    steps = steps or (100 if quick else None)  # None: each preset's own length, as a user trains it
    rows = {f"{kind}_{seed} seed {s}": clip_avatars(base, kind, seed, threads, steps, s)
            for s in range(seeds or 1) for kind, seed in clips}
    mean_gaps = {move: {preset: round(float(np.mean([row["gaps"][move][preset] for row in rows.values()])), 3)
                        for preset in PRESETS} for move in MOVES}
    return {"benchmark": "track_avatar", "split": split, "threads": threads,
            "load_average": [round(x, 2) for x in os.getloadavg()], "avatars": rows,
            "mean_gap_db_truth_minus_tracked": mean_gaps, "bar_gap_db": 1.5}
