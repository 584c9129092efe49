"""Benchmark: an avatar trained on a tracked phone clip against one trained on the clip's truth.

The paper's camera-free table, measured here. From one test clip of ``bench track`` (made and
tracked there first): a second capture is written with the same images, masks and splits but the
truth's cameras and FLAME parameters (``truth_capture``). Both are trained alike, with and without
the method's corrections (``demo`` and ``mogaface-demo``, each its own length unless ``steps``),
and drawn at the truth's novel cameras, which the footage never saw, at the frames it rendered
them: the truth-trained avatar at those cameras as they are, the tracked one at those cameras
moved from the true head to the tracked head (the two heads' poses at that frame), as the aligned
novel-view protocol moves a held-out camera. PSNR against the truth's renders (white background). Trained avatars are kept
and reused (each step count its own); the tracked one is trained again when the clip was tracked
again since.
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


def novel_psnr(run: pathlib.Path, clip: pathlib.Path, tracked_report: dict, move: bool) -> dict:
    """PSNR of ``run``'s avatar at the truth's novel cameras (moved onto the tracked head if ``move``)."""
    import torch

    from mogaface.core.camera import Camera
    from mogaface.core.data.camera_file import read_cameras
    from mogaface.core.evaluate.track_error import head_to_world, vertices_and_joints
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
        shift = np.eye(4)
        if move:
            true_params = load_npz(truth / "flame_param" / f"{frame:05d}.npz")
            true_head = head_to_world(true_params, vertices_and_joints(true_model, true_params, True)[1])
            fit_head = head_to_world(params, vertices_and_joints(fit_model, params, True)[1])
            shift = true_head @ np.linalg.inv(fit_head)  # tracked head's frame → true head's frame
        for camera_id, camera in novel.items():
            moved = Camera(K=camera.K, w2c=camera.w2c @ shift, width=camera.width, height=camera.height,
                           camera_id=camera_id)
            torch_params = {k: torch.as_tensor(np.asarray(v, np.float32).reshape(1, -1)) for k, v in params.items()
                            if k != "static_offset"}
            with torch.no_grad():
                rendered = avatar.render(torch_params, moved, (1.0, 1.0, 1.0)).rgb.clamp(0, 1).numpy()
            target = read_image(truth / info["images"].format(frame=frame, camera=camera_id))[..., :3]
            scores.append(metrics.psnr(rendered, target))
    return {"views": len(scores), "psnr": round(float(np.mean(scores)), 3) if scores else None}


def _trained_after(avatar: pathlib.Path, tracking: pathlib.Path) -> bool:
    """Whether ``avatar`` exists and was trained after its capture was tracked (the truth's capture
    has no ``tracking`` file: its avatar never goes stale)."""
    return avatar.is_file() and (not tracking.is_file() or avatar.stat().st_mtime > tracking.stat().st_mtime)


def run(threads: int = 2, quick: bool = False, work: str | None = None, split: str | None = None,
        steps: int | None = None) -> dict:
    from mogaface.core.train import config as C
    from mogaface.core.train.trainer import Trainer

    from .track import CLIPS

    kind, seed = CLIPS[split or "test"][0]
    base = pathlib.Path(work or "out/bench_track") / ("quick" if quick else "full")
    clip, tracked = base / f"{kind}_{seed}", base / "tracked" / f"{kind}_{seed}"
    if not (tracked / "tracking.json").is_file():
        raise SystemExit(f"error: {tracked}: run `bench track --split {split or 'test'}` first")
    report = json.loads((tracked / "tracking.json").read_text())
    truth_cap = truth_capture(clip, tracked, base / "truth_capture" / f"{kind}_{seed}")
    steps = steps or (100 if quick else None)  # None: each preset's own length, as a user trains it
    rows, lengths = {}, {}
    for preset in PRESETS:
        train = {"threads": threads, **({"steps": steps} if steps else {})}
        config = C.resolve(preset=preset, overrides={"train": train, "eval": {"at_end": False}})
        lengths[preset] = config.train.steps
        for name, capture in (("tracked", tracked), ("truth", truth_cap)):
            run_dir = base / "avatars" / f"{kind}_{seed}_{name}_{preset}" / f"steps{config.train.steps}"
            if not _trained_after(run_dir / "avatar.pt", capture / "tracking.json"):
                shutil.rmtree(run_dir, ignore_errors=True)
                Trainer(capture, run_dir, config).run()
            rows[f"{preset} {name}"] = novel_psnr(run_dir, clip, report, move=name == "tracked")
    gaps = {preset: round(rows[f"{preset} truth"]["psnr"] - rows[f"{preset} tracked"]["psnr"], 3)
            for preset in PRESETS if rows[f"{preset} truth"]["psnr"] and rows[f"{preset} tracked"]["psnr"]}
    return {"benchmark": "track_avatar", "clip": f"{kind}_{seed}", "steps": lengths, "threads": threads,
            "load_average": [round(x, 2) for x in os.getloadavg()], "novel_view_psnr": rows,
            "gap_db_truth_minus_tracked": gaps, "bar_gap_db": 1.5}
