"""Headless MoGaFace in Blender: capture → (train) → head with keyframes → rendered frames → .blend.

Runs the same with the Blender binary and with the ``bpy`` module:

    blender -b --python scripts/mogaface_blend.py -- CAPTURE --run RUN --blend OUT.blend [options]
    blender -b --factory-startup --python scripts/mogaface_blend.py -- …   (the extension is enabled here)
    blender -b SCENE.blend --python scripts/mogaface_blend.py -- …         (built into SCENE's content)
    python scripts/mogaface_blend.py CAPTURE --run RUN --blend OUT.blend [options]

From the artist's own clip, and a performance on another avatar:

    blender -b --python scripts/mogaface_blend.py -- CAPTURE --footage CLIP.mp4 --train --run RUN --blend OUT.blend
    blender -b --python scripts/mogaface_blend.py -- CAPTURE --run OTHER_RUN --drive PERFORMANCE.mp4 --blend OUT.blend

Steps: install what this Blender lacks (``--install-dependencies``); track ``--footage`` (a video,
photos or a photo folder) into CAPTURE as Track Footage does (camera, tracked head, the footage
behind it), else import the capture's cameras; train into RUN (``--train``; otherwise RUN must hold a
trained avatar); import the avatar's head with the run's identity; key its expressions and pose
from the run's corrected tracking (``RUN/flame_param_corrected`` of a MoGaFace run, else
``RUN/flame_param``; or ``--tracking``), or from a performance clip (``--drive``, as Drive from
Footage does: tracked with the head's shape held fixed, at the scene's frame rate); link the avatar; render
a frame range from one capture camera into image datablocks (and files with ``--render-dir``);
save the ``.blend`` with the images packed. Exit code 0 on success, 1 on any reported error.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pathlib
import sys
import time

#: The training presets offered here (as in the panel), with a one-line description each.
PRESETS = (
    ("quick", "smoke run, 200 steps"),
    ("demo", "1000 steps, a recognisable avatar"),
    ("full", "the defaults, about 15 minutes on two cores"),
    ("mogaface", "the full MoGaFace method, default length"),
    ("mogaface-demo", "the full MoGaFace method at the demo's length"),
)


def script_arguments(argv=None) -> list[str]:
    """The script's own arguments: after ``--`` (Blender binary), else everything (``python``)."""
    argv = list(sys.argv if argv is None else argv)
    if "--" in argv:
        return argv[argv.index("--") + 1:]
    return argv[1:]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mogaface_blend.py",
        description="Build a Blender scene of a trained MoGaFace avatar headlessly: import a capture and the "
        "avatar's head, optionally train, key the run's tracking, render a frame range, save a .blend.",
    )
    parser.add_argument("capture", type=pathlib.Path, help="capture folder (GaussianAvatars/VHAP layout)")
    parser.add_argument("--run", type=pathlib.Path, required=True, help="run folder (trained, or written by --train)")
    parser.add_argument("--blend", type=pathlib.Path, required=True, help="the .blend file to write")
    parser.add_argument("--train", action="store_true", help="train into --run first (a separate process)")
    parser.add_argument("--install-dependencies", action="store_true",
                        help="first install what this Blender lacks, as the panel's button does: the Python packages "
                        "and the LPIPS weights a run's end-of-run scoring needs (needs online access: "
                        "blender --online-mode, or the preference)")
    parser.add_argument("--preset", default="demo", choices=[name for name, _ in PRESETS],
                        help="training preset: " + "; ".join(f"{name}: {text}" for name, text in PRESETS))
    parser.add_argument("--steps", type=int, default=0, help="training steps (0: the preset's)")
    parser.add_argument("--camera-rounds", type=int, default=0,
                        help="refine the cameras in this many rounds while training (0: trust the calibration)")
    parser.add_argument("--python", help="interpreter for the training process (default: this one)")
    parser.add_argument("--launcher", help="start training through this command line, e.g. "
                        "'torchrun --nproc_per_node 2' (data-parallel; see docs/training.md)")
    parser.add_argument("--tracking", type=pathlib.Path,
                        help="flame_param folder to key on the head (default: the run's corrected tracking, "
                        "RUN/flame_param_corrected or RUN/flame_param)")
    parser.add_argument("--footage", type=pathlib.Path, nargs="+", metavar="CLIP",
                        help="first track this video (or these photos, or a photo folder) into CAPTURE (a new or "
                        "empty folder), as the panel's Track Footage does")
    parser.add_argument("--track-size", type=int, default=512, help="longer side of the tracked frames (default 512)")
    parser.add_argument("--fit-steps", type=int, default=200, help="iterations of the tracker's fit (default 200)")
    parser.add_argument("--drive", type=pathlib.Path, metavar="CLIP",
                        help="a performance clip that drives the avatar's head instead of the run's tracking, as "
                        "Drive from Footage does (tracked with the head's shape held fixed)")
    parser.add_argument("--drive-out", type=pathlib.Path,
                        help="where the performance's flame_param files go (default: beside the clip)")
    parser.add_argument("--fps", type=float, help="the scene's frame rate: the performance is retimed to it "
                        "(default: the scene's, 24; a tracked clip sets its own)")
    parser.add_argument("--tolerance", type=float, default=0.001,
                        help="keys of the performance within this of the curve are dropped (default 0.001)")
    parser.add_argument("--keep-head-still", action="store_true",
                        help="the performance moves only the face: the head keeps its pose")
    parser.add_argument("--camera", help="capture camera id to render from (default: the capture's val camera, "
                        "else its first)")
    parser.add_argument("--frames", type=int, nargs=2, metavar=("START", "END"),
                        help="frame range to render (default: the first 8 frames of the tracking)")
    parser.add_argument("--render-dir", type=pathlib.Path, help="also write the rendered frames here")
    parser.add_argument("--format", default="PNG", choices=["PNG", "EXR", "BOTH"], help="file format of --render-dir")
    return parser


def _mogaface_module():
    """The MoGaFace package, registered: an enabled extension, an installed one (enabled here:
    ``--factory-startup`` starts with every extension off), or the importable package."""
    import importlib

    import bpy

    enabled = [name for name in bpy.context.preferences.addons.keys() if name.split(".")[-1] == "mogaface"]
    if not enabled:
        for repo in bpy.context.preferences.extensions.repos:
            if repo.enabled and os.path.isfile(os.path.join(repo.directory, "mogaface", "__init__.py")):
                module = f"bl_ext.{repo.module}.mogaface"
                if "FINISHED" in bpy.ops.preferences.addon_enable(module=module):
                    enabled.append(module)
                    break
    if enabled:
        return importlib.import_module(enabled[0])
    try:
        import mogaface
    except ImportError:
        raise SystemExit("error: MoGaFace is neither an installed extension nor an importable package") from None
    if not hasattr(bpy.types, "MOGAFACE_OT_import_head"):
        mogaface.register()
    return mogaface


def _call(operator, **kwargs) -> None:
    """Run an operator; its error reports become a clean exit with the message."""
    try:
        result = operator(**kwargs)
    except RuntimeError as error:
        raise SystemExit(f"error: {str(error).strip()}") from None
    if "FINISHED" not in result:
        raise SystemExit(f"error: {operator.idname_py()} did not finish ({', '.join(result)})")


def _check_output(path: pathlib.Path) -> None:
    """The core's output check (a device, FIFO, socket or folder is never replaced) as a clean exit."""
    atomic = importlib.import_module(f"{_mogaface_module().__name__}.core.io.atomic")
    try:
        atomic.check_output_target(path)
    except ValueError as error:
        raise SystemExit(f"error: {error}") from None


def _default_camera(capture: pathlib.Path) -> str:
    mogaface = _mogaface_module()
    core_capture = __import__(f"{mogaface.__name__}.core.data.capture", fromlist=["Capture"])
    opened = core_capture.Capture.open(capture)
    if opened.splits.get("val"):
        return opened.splits["val"][0].camera_id
    return next(iter(opened.cameras))


def build_scene(args, log=print) -> dict:
    """Everything after the arguments: the scene, the renders, the saved .blend. Returns a summary."""
    import bpy

    start = time.monotonic()
    if not bpy.data.filepath:  # no .blend given: an empty scene (preferences and extensions kept)
        bpy.ops.wm.read_homefile(use_empty=True)
    mogaface = _mogaface_module()
    ops = bpy.ops.mogaface
    _check_output(args.blend)
    if args.install_dependencies:
        _call(ops.install_dependencies)
        log("[blend] installed the dependencies")
    run = args.run.resolve()
    if args.footage:
        paths = [path.resolve() for path in args.footage]
        files = {"filepath": str(paths[0])} if len(paths) == 1 else {
            "directory": str(paths[0].parent), "files": [{"name": path.name} for path in paths]}
        _call(ops.track_footage, out=str(args.capture.resolve()), size=args.track_size, fit_steps=args.fit_steps,
              **files)
        log(f"[blend] tracked {len(paths)} input(s) into {args.capture}: camera, tracked head and footage imported")
    else:
        _call(ops.import_capture, filepath=str(args.capture.resolve()))
        log(f"[blend] imported the capture's cameras from {args.capture}")
    if args.train:
        addon = bpy.context.preferences.addons.get(mogaface.__name__)
        if addon is not None and args.launcher:
            addon.preferences.launcher = args.launcher
        weights = importlib.import_module(f"{mogaface.__name__}.core.metrics.lpips_weights")
        if not weights.installed():
            log("[blend] the LPIPS weights are missing: the run is scored without LPIPS (--install-dependencies)")
        _call(ops.train, capture=str(args.capture.resolve()), run=str(run), preset=args.preset, steps=args.steps,
              resume="NEW", python=args.python or "", camera_rounds=args.camera_rounds)
        log(f"[blend] trained into {run}")
    names = importlib.import_module(f"{mogaface.__name__}.core.run.names")
    head = run / f"{names.HEAD_STEM}.pkl"
    if not head.exists():
        head = run / f"{names.HEAD_STEM}.npz"
    corrected = run / names.CORRECTED_DIR  # a MoGaFace run's improved tracking (same as flame_param)
    tracking = (args.tracking or (corrected if corrected.is_dir() else run / names.FLAME_PARAM_DIR)).resolve()
    identity = sorted((run / names.FLAME_PARAM_DIR).glob("*.npz"))  # the avatar's own identity
    _call(ops.import_head, filepath=str(head), shape_file=str(identity[0]) if identity else "")
    head_object = bpy.context.active_object
    scene = bpy.context.scene
    _call(ops.import_tracking, directory=str(tracking), target=head_object.name)
    if args.drive:  # the performance is put on the pose the avatar shows at its first tracked frame
        scene.frame_set(scene.frame_start)
        if args.fps:
            scene.render.fps, scene.render.fps_base = max(1, round(args.fps)), max(1, round(args.fps)) / args.fps
        _call(ops.drive_from_footage, filepath=str(args.drive.resolve()), target=head_object.name,
              out=str(args.drive_out.resolve()) if args.drive_out else "", tolerance=args.tolerance,
              keep_head_still=args.keep_head_still, size=args.track_size, fit_steps=args.fit_steps)
        tracking = pathlib.Path(scene.mogaface.tracking_folder)
    _call(ops.load_avatar, filepath=str(run), target=head_object.name)
    log(f"[blend] head {head_object.name!r} keyed from {tracking}, avatar linked")
    camera_id = args.camera or _default_camera(args.capture)
    camera = next((o for o in scene.objects if o.get("mogaface_camera_id") == camera_id), None)
    if camera is None:
        raise SystemExit(f"error: the capture has no camera {camera_id!r}")
    sys.modules[f"{mogaface.__name__}.operators.import_capture"].apply_render_settings(scene, camera)
    first, last = args.frames or (scene.frame_start, min(scene.frame_end, scene.frame_start + 7))
    _call(ops.render_animation, head=head_object.name, frame_start=first, frame_end=last,
          directory=str(args.render_dir.resolve()) if args.render_dir else "", file_format=args.format)
    images = [image.name for image in bpy.data.images if image.name.startswith("MoGaFace ")]
    log(f"[blend] rendered frames {first}..{last} from {camera.name} ({len(images)} images)")
    scene.frame_set(first)
    args.blend.parent.mkdir(parents=True, exist_ok=True)
    blend = args.blend.absolute()  # not resolved: a link named as the output is replaced, never followed
    tmp = blend.with_name(blend.stem + ".tmp.blend")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp), compress=True)
    _check_output(blend)
    os.replace(tmp, blend)
    log(f"[blend] saved {blend} in {time.monotonic() - start:.1f} s")
    return {"blend": str(blend), "camera": camera.name, "frames": [first, last], "images": images,
            "head": head_object.name, "tracking": str(tracking)}


def main(argv=None) -> int:
    args = build_parser().parse_args(script_arguments(argv))
    try:
        build_scene(args)
    except SystemExit as stop:
        if isinstance(stop.code, str):
            print(stop.code, file=sys.stderr)
            return 1
        raise
    return 0


if __name__ == "__main__":
    code = main()
    if code:
        sys.exit(code)
