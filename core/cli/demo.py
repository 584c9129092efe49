"""``demo --out DIR``: the whole job on the embedded default head, end to end, on the CPU.

Makes the default capture of subject 0 and a small one of subject 1 (the cross-identity
driver), trains an avatar, evaluates it, exports a world-space PLY, renders subject 1's motion
on subject 0's avatar, builds a Blender scene with the headless script, and writes a one-page
``report.md``. ``--tiny`` shrinks every stage to a smoke run of well under a minute.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

from ..errors import InputError

ROOT = pathlib.Path(__file__).resolve().parents[2]
BLEND_SCRIPT = ROOT / "scripts" / "mogaface_blend.py"


@dataclasses.dataclass
class DemoPlan:
    """The sizes of every stage (the full demo, or the ``--tiny`` smoke run)."""

    views: int = 16
    timesteps: int = 150
    size: int = 256
    supersample: int = 3
    driver_timesteps: int = 48
    steps: int | None = None  # None: the preset's
    eval_frames: int = 24
    lpips: bool = True
    blend_frames: int = 8


TINY = DemoPlan(views=3, timesteps=16, size=48, supersample=1, driver_timesteps=16, steps=20, eval_frames=3,
                lpips=False, blend_frames=3)


def training_preset() -> str:
    """The demo's training preset, chosen here only: MoGaFace's own once the trainer has one."""
    from ..train.config import PRESETS

    return next((name for name in ("mogaface-demo", "mogaface") if name in PRESETS), "demo")


def add_arguments(parser):
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/demo"),
                        help="output folder: new or empty, unless --overwrite")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into a non-empty --out, replacing its run/, capture/ and driver_capture/")
    parser.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")
    parser.add_argument("--tiny", action="store_true", help="a smoke run: tiny capture, a few steps (< 1 min)")
    parser.add_argument("--no-blend", action="store_true", help="skip the Blender scene (needs the bpy module)")


class _Clock:
    """Per-stage wall times, printed as the demo goes."""

    def __init__(self):
        self.start = time.monotonic()
        self.stages: dict[str, float] = {}

    def stage(self, name: str, began: float, note: str = "") -> None:
        self.stages[name] = round(time.monotonic() - began, 1)
        print(f"[demo] {name}: {self.stages[name]:.1f} s{' — ' + note if note else ''}", flush=True)

    @property
    def total(self) -> float:
        return round(time.monotonic() - self.start, 1)


def make_captures(out: pathlib.Path, plan: DemoPlan, seed: int) -> tuple[pathlib.Path, pathlib.Path]:
    from ..data.generator import CaptureSettings, make_capture

    capture, driver = out / "capture", out / "driver_capture"
    for folder in (capture, driver):
        if folder.exists():
            shutil.rmtree(folder)
    make_capture(capture, CaptureSettings(subject=0, views=plan.views, timesteps=plan.timesteps, size=plan.size,
                                          supersample=plan.supersample, seed=seed), progress=True)
    # The driver only lends its tracked motion: few small views are enough.
    make_capture(driver, CaptureSettings(subject=1, views=2, timesteps=plan.driver_timesteps, size=48,
                                         supersample=1, seed=seed + 1), progress=False)
    return capture, driver


def train(capture: pathlib.Path, run: pathlib.Path, plan: DemoPlan, seed: int) -> dict:
    import argparse

    from ..train import config as config_module
    from ..train.trainer import Trainer
    from .train import _listeners

    if run.exists():
        shutil.rmtree(run)
    overrides = {"train": {"seed": seed, **({"steps": plan.steps} if plan.steps else {})}}
    config = config_module.resolve(training_preset(), None, overrides)
    listeners = _listeners(argparse.Namespace(events="file", quiet=False))
    trainer = Trainer(capture, run, config, listeners=listeners)
    trainer.install_signal_handlers()
    result = trainer.run()
    print(file=sys.stderr)
    return result


def val_camera(capture: pathlib.Path) -> str:
    from ..data.capture import Capture

    opened = Capture.open(capture)
    return opened.splits["val"][0].camera_id if opened.splits.get("val") else next(iter(opened.cameras))


def export_ply(run: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
    from ..avatar.export import export_world_ply
    from ..run.folder import RunFolder

    folder = RunFolder(run)
    timestep = folder.trained_timesteps[0]
    return export_world_ply(folder.load_avatar(), folder.flame_params(timestep),
                            out / f"avatar_world_t{timestep:05d}.ply")


def write_gif(frames: list[pathlib.Path], path: pathlib.Path, duration_ms: int = 100) -> pathlib.Path | None:
    """An animated GIF of PNG frames (None without pillow)."""
    try:
        from PIL import Image
    except ImportError:
        return None
    from ..io.atomic import atomic_path

    images = [Image.open(p).convert("RGB") for p in frames]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)
    return path


def build_blend(capture: pathlib.Path, run: pathlib.Path, out: pathlib.Path, camera: str, frames: int):
    """Run the headless Blender script in a child process (its own temporary Blender user folder)."""
    import importlib.util

    if importlib.util.find_spec("bpy") is None:
        return None, "the bpy module is not installed here (pip install bpy==5.0.1)"
    user = tempfile.mkdtemp(prefix="mogaface-demo-blender-")
    env = {**os.environ, **{v: user for v in ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG",
                                              "BLENDER_USER_SCRIPTS")}}
    command = [sys.executable, str(BLEND_SCRIPT), str(capture), "--run", str(run), "--blend",
               str(out / "demo.blend"), "--camera", camera, "--render-dir", str(out / "frames"),
               "--frames", "1", str(frames)]
    try:
        result = subprocess.run(command, env=env, capture_output=True, text=True)
    finally:
        shutil.rmtree(user, ignore_errors=True)
    for line in result.stdout.splitlines():
        if line.startswith("[blend]"):
            print(line, flush=True)
    if result.returncode != 0:
        return None, (result.stderr.strip().splitlines() or ["failed"])[-1]
    return out / "demo.blend", None


def _rel(path, out: pathlib.Path) -> str:
    return os.path.relpath(path, out)


def write_report(out: pathlib.Path, facts: dict, metrics_md: str, clock: _Clock) -> pathlib.Path:
    from ..io.atomic import write_text

    lines = [
        "# MoGaFace demo",
        "",
        f"Everything below was produced by `python -m mogaface demo --out {facts['out_arg']}` on the CPU "
        f"in {clock.total / 60:.1f} minutes (seed {facts['seed']}{', tiny smoke run' if facts['tiny'] else ''}).",
        "",
        "## What was done",
        "",
        f"1. A synthetic capture of the procedural head, subject 0 ({facts['capture_summary']}), and a small "
        "one of subject 1 whose tracked motion drives subject 0 below (`capture/`, `driver_capture/`).",
        f"2. Training with the `{facts['preset']}` preset: {facts['steps']} steps, "
        f"{facts['gaussians']} Gaussians at the end (`run/`).",
        "3. Evaluation on the novel-view (the held-out frontal camera) and self-reenactment (the held-out "
        f"sequence) protocols, at most {facts['eval_frames']} frames each (`metrics.json`, `metrics.md`, `eval/`).",
        f"4. The posed Gaussians of one timestep as a world-space 3DGS PLY (`{facts['ply']}`).",
        "5. Cross-identity reenactment: subject 1's tracking driving subject 0's avatar, seen by the held-out "
        f"frontal camera (`eval/cross_identity/`, `{facts['gif'] or 'no GIF: pillow missing'}`).",
        f"6. A Blender scene built headlessly by `scripts/mogaface_blend.py`: {facts['blend_note']}",
        "",
        "## Images",
        "",
    ]
    for title, path in facts["images"]:
        lines += [f"**{title}**", "", f"![{title}]({path})", ""]
    table = [line for line in metrics_md.splitlines() if not line.startswith("# ")]
    lines += ["## Metrics", "", "\n".join(table).strip(), "",
              "PSNR in dB on the whole image over the training background; SSIM; LPIPS (AlexNet, lower is "
              "better). Frames are spread evenly over each protocol's views.", "",
              "## Timings", "", "| stage | seconds |", "|---|---|"]
    lines += [f"| {name} | {seconds:.1f} |" for name, seconds in clock.stages.items()]
    lines += [f"| **total** | **{clock.total:.1f}** |", ""]
    path = out / "report.md"
    write_text(path, "\n".join(lines))
    return path


def run(args) -> int:
    from ..data.head_preview import render_preview_sheet
    from ..evaluate.evaluation import evaluate_run
    from ..evaluate.report import markdown_table, strip_image
    from ..flame.model_file import write_model_file
    from ..flame.procedural import build_head
    from ..io.atomic import write_json
    from ..io.image import read_image, write_png
    from ..run.folder import RunFolder

    plan = TINY if args.tiny else DemoPlan()
    out = args.out.resolve()
    if out.exists() and not out.is_dir():
        raise InputError(out, None, "--out must be a folder")
    if out.is_dir() and any(out.iterdir()) and not args.overwrite:
        raise InputError(out, None, "not empty; choose a new folder, or pass --overwrite to replace the demo's "
                                    "outputs there (run/, capture/, driver_capture/ are deleted first)")
    out.mkdir(parents=True, exist_ok=True)
    clock = _Clock()
    preset = training_preset()
    print(f"[demo] into {out} (training preset {preset!r}{', tiny' if args.tiny else ''})", flush=True)

    began = time.monotonic()
    head_path = out / "head.pkl"
    write_model_file(head_path, build_head(subject=0, seed=args.seed))
    sheet, tiles = render_preview_sheet(head_path)
    write_png(out / "preview" / "contact_sheet.png", sheet)
    clock.stage("head preview", began, f"{head_path.name}, preview/contact_sheet.png")

    began = time.monotonic()
    capture, driver = make_captures(out, plan, args.seed)
    clock.stage("captures", began, f"{plan.views} views × {plan.timesteps} timesteps at {plan.size}²")

    began = time.monotonic()
    run_dir = out / "run"
    result = train(capture, run_dir, plan, args.seed)
    if not result["complete"]:
        print(f"[demo] training stopped at step {result['step']} (checkpoint in {run_dir}); demo ends here",
              file=sys.stderr)
        return 130
    clock.stage("training", began, f"{result['step']} steps")

    began = time.monotonic()
    camera = val_camera(capture)
    metrics = evaluate_run(run_dir, max_frames=plan.eval_frames, lpips=plan.lpips, driver=driver, out_dir=out,
                           progress=True, driver_cameras=[camera])
    clock.stage("evaluation + cross-identity", began, "metrics.json, metrics.md, eval/")

    began = time.monotonic()
    ply = export_ply(run_dir, out)
    cross = sorted((out / "eval" / "cross_identity").glob(f"*_{camera}.png"))
    gif = write_gif(cross, out / "cross_identity.gif") if cross else None
    clock.stage("PLY + clip", began, f"{ply.name}, {gif.name if gif else 'no GIF'}")

    began = time.monotonic()
    blend, problem = (None, "skipped (--no-blend)") if args.no_blend else \
        build_blend(capture, run_dir, out, camera, plan.blend_frames)
    frames = sorted((out / "frames").glob("*.png")) if blend else []
    if frames:
        write_png(out / "frames_strip.png", strip_image([[read_image(p)[..., :3] for p in frames]]))
    clock.stage("Blender scene", began, str(blend.name) if blend else f"not built: {problem}")

    run_info = RunFolder(run_dir).info
    images = [("The procedural head (subject 0)", "preview/contact_sheet.png")]
    for protocol in ("novel_view", "self_reenactment"):
        for p in sorted((out / "eval").glob(f"{protocol}_*.png"))[:1]:
            images.append((f"{protocol.replace('_', ' ').capitalize()}, timestep {p.stem.split('_')[-2]}: "
                           "rendered | ground truth | error ×4", _rel(p, out)))
    if (out / "eval" / "cross_identity" / "strip.png").exists():
        images.append(("Cross-identity: subject 1's motion on subject 0's avatar",
                       "eval/cross_identity/strip.png"))
    if gif:
        images.append(("Cross-identity clip", _rel(gif, out)))
    if frames:
        images.append(("Rendered in Blender from the keyframed head (frames 1…)", "frames_strip.png"))
    facts = {
        "out_arg": args.out, "seed": args.seed, "tiny": args.tiny, "preset": preset,
        "capture_summary": f"{plan.views} cameras, {plan.timesteps} timesteps, {plan.size}² pixels",
        "steps": run_info.get("final_step"), "gaussians": run_info.get("gaussians"),
        "eval_frames": plan.eval_frames, "ply": ply.name, "gif": gif.name if gif else None,
        "blend_note": (f"`demo.blend` with the capture's cameras, the head keyed from the run's corrected tracking and "
                       f"{len(frames)} rendered frames as packed images (`frames/`)." if blend
                       else f"not built ({problem})."),
        "images": images,
    }
    write_json(out / "timings.json", {"stages_s": clock.stages, "total_s": clock.total})
    report = write_report(out, facts, markdown_table(metrics), clock)
    print(f"[demo] report → {report}", flush=True)
    print(f"[demo] done in {clock.total:.1f} s", flush=True)
    return 0
