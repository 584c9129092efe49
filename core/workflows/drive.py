"""A performance clip drives an avatar: the clip tracked with the avatar's head shape held fixed, its
expression, jaw, eyes and head motion retimed to the scene's frame rate, written as ``flame_param``
files (the folder ``render --params`` and Blender's Import Tracking read).

The head's motion is carried over relative to the performer's mean pose and put on the avatar's
rest pose (its first tracked timestep, or the pose a Blender head shows), so a performance filmed
at arm's length drives an avatar captured by a dome; with ``keep_head_still`` the avatar keeps its
rest pose and only the face moves. Keys are thinned within a tolerance
(:func:`~..scene.tracking.thin_channel`: the same for the command line's files and Blender's
F-curves), so a scene carries only the keys that matter and both play the same values.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import tempfile

import numpy as np

from ..errors import InputError

#: The per-frame channels a performance carries (FLAME names), identity excluded.
CHANNELS = ("expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation")
#: The channels of the head's motion (kept still on request).
HEAD_MOTION = ("rotation", "neck_pose", "translation")
REPORT_FILE = "drive.json"


@dataclasses.dataclass
class Identity:
    """What a performance is put on: the head model file, its shape (and static offset), its rest pose."""

    head_file: pathlib.Path
    shape: np.ndarray
    static_offset: np.ndarray | None
    rest: dict  # rotation, neck_pose, translation of the avatar at rest

    @classmethod
    def of(cls, path, head_file=None) -> "Identity":
        """A run folder, a capture folder, or an ``.npz`` with ``shape`` (then ``head_file`` is needed;
        its ``rotation``/``neck_pose``/``translation``, if any, are the rest pose)."""
        from ..data.capture import Capture
        from ..data.capture_info import capture_head_file
        from ..run.folder import RunFolder

        path = pathlib.Path(path)
        if path.is_file():
            if head_file is None:
                raise InputError(path, None, "an identity file needs the head model it belongs to (--head)")
            from ..io.npz import load_npz
            from ..limits import MAX_PARAM_FILE_BYTES

            params = load_npz(path, MAX_PARAM_FILE_BYTES)
        elif (path / "run.json").is_file():
            run = RunFolder(path)
            capture = Capture.open(run.capture_root)
            params = dict(capture.flame_params(capture.timesteps[0]))
            params.update(run.identity_params() or {})
            trained = run.head_path(".pkl")
            head_file = head_file or (trained if trained.is_file() else capture_head_file(run.capture_root))
        elif path.is_dir():
            capture = Capture.open(path)
            params = capture.flame_params(capture.timesteps[0])
            head_file = head_file or capture_head_file(path)
        else:
            raise InputError(path, None, "expected a run folder, a capture folder or an .npz with 'shape'")
        if "shape" not in params:
            raise InputError(path, "shape", f"missing (the file has {sorted(params)})")
        rest = {}
        for name in HEAD_MOTION:
            value = np.asarray(params.get(name, np.zeros(3)), np.float64).reshape(-1)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise InputError(path, name, f"expected 3 finite numbers, found {value.shape}")
            rest[name] = value
        offset = params.get("static_offset")
        shape = np.asarray(params["shape"], np.float64).reshape(-1)
        if not np.isfinite(shape).all():
            raise InputError(path, "shape", "expected finite numbers")
        return cls(pathlib.Path(head_file), shape,
                   None if offset is None else np.asarray(offset, np.float64).reshape(-1, 3), rest)


# -- retiming, retargeting, thinning (no torch) -------------------------------------------------
def retime(values: np.ndarray, fps_in: float, fps_out: float) -> np.ndarray:
    """``values (T,n)`` sampled at ``fps_in`` resampled at ``fps_out`` (linear), over the same span."""
    values = np.asarray(values, np.float64)
    if fps_in <= 0 or fps_out <= 0:
        raise InputError(None, "fps", f"expected positive frame rates, got {fps_in} and {fps_out}")
    if len(values) < 2 or abs(fps_in - fps_out) < 1e-9:
        return values.copy()
    span = (len(values) - 1) / fps_in
    times = np.arange(int(np.floor(span * fps_out + 1e-9)) + 1) / fps_out
    source = np.arange(len(values)) / fps_in
    return np.stack([np.interp(times, source, values[:, i]) for i in range(values.shape[1])], 1)


def _matrices(axis_angle: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis_angle).as_matrix()


def _axis_angles(matrices: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(matrices).as_rotvec()


def put_on_rest(params: dict, rest: dict, seen: np.ndarray | None = None, keep_head_still: bool = False) -> dict:
    """The performer's head motion relative to their mean pose (over ``seen`` frames), put on the
    avatar's ``rest`` pose; ``keep_head_still``: the rest pose in every frame."""
    frames = len(params["expr"])
    out = {name: np.asarray(value, np.float64).copy() for name, value in params.items()}
    seen = np.ones(frames, bool) if seen is None or not np.any(seen) else np.asarray(seen, bool)
    for name in HEAD_MOTION:
        still = np.tile(np.asarray(rest.get(name, np.zeros(3)), np.float64).reshape(1, 3), (frames, 1))
        if keep_head_still:
            out[name] = still
        elif name == "translation":
            out[name] = still + out[name] - out[name][seen].mean(0)
        else:
            from scipy.spatial.transform import Rotation

            mean = Rotation.from_rotvec(out[name][seen]).mean().as_matrix()
            out[name] = _axis_angles(_matrices(out[name]) @ mean.T @ _matrices(still))
    return out


# -- the drive ---------------------------------------------------------------------------------
@dataclasses.dataclass
class DriveSettings:
    fps: float | None = None  # the target frame rate (None: the clip's)
    keep_head_still: bool = False
    tolerance: float = 0.0  # keys within this of the curve are dropped (radians, metres, coefficients)
    fit_steps: int = 200
    photometric_steps: int | None = None  # None: those chosen for a video (photometric.CHOSEN)
    photometric_stride: int | None = None  # None: the one chosen for a video (photometric.CHOSEN)
    size: int | None = 512
    threads: int = 2


def drive_clip(clip, identity: Identity, out, settings: DriveSettings = DriveSettings(), selection=None,
               capture=None, progress=None) -> dict:
    """Track ``clip`` with ``identity``'s shape held fixed and write its performance to the
    ``flame_param`` folder ``out`` (new or empty), retimed to ``settings.fps``, with ``drive.json``.
    ``capture``: keep the tracked capture there (default: a temporary folder, removed).
    ``progress(stage, done, total)`` as :func:`~.pipeline.track_footage` calls it."""
    from ..io.atomic import check_output_target
    from ..track.fit import FitSettings
    from ..track.photometric import PhotometricSettings
    from ..track.pipeline import TrackSettings, track_footage

    out = pathlib.Path(out)
    check_output_target(out, folder=True)
    if out.exists() and any(out.iterdir()):
        raise InputError(out, None, "is not empty; expected a new or empty folder")
    work = tempfile.TemporaryDirectory(prefix=".mogaface-drive-", dir=out.parent if out.parent.is_dir() else None)
    try:
        tracked = pathlib.Path(capture) if capture is not None else pathlib.Path(work.name) / "capture"
        track = TrackSettings(size=settings.size, threads=settings.threads, head_file=identity.head_file,
                              fit=FitSettings(steps=settings.fit_steps, shape=identity.shape,
                                              photometric=PhotometricSettings(steps=settings.photometric_steps,
                                                                              stride=settings.photometric_stride)))
        report = track_footage(clip, tracked, track, selection, progress)
        performance = _tracked_params(tracked, report["frames"])
        clip_fps = float(report.get("fps") or 0) or (settings.fps or 30.0)
        result = performance_frames(performance, report["lost_frames"], clip_fps, identity, settings)
        staged = pathlib.Path(work.name) / "flame_param"
        result["files"] = write_performance(staged, result.pop("params"), identity)
        result.update(source=str(report["source"]), tracked_frames=report["frames"],
                      reprojection_px=report["reprojection_px"]["mean"], head_model=str(identity.head_file))
        from ..io.atomic import write_json

        write_json(staged / REPORT_FILE, result)
        if out.exists():
            out.rmdir()
        out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged, out)
        return result
    finally:
        work.cleanup()


def thin_channel(values: np.ndarray, tolerance: float, at=None) -> np.ndarray:
    """Indices of the keys of one channel ``(T,)`` (at frames ``at``, default 0…T-1) to keep so that
    linear interpolation between them stays within ``tolerance`` of every value
    (Ramer-Douglas-Peucker); the ends are always kept. Thinned keys play a performance back
    within the tolerance, and a curve that holds still keeps two keys instead of one per frame."""
    values = np.asarray(values, np.float64)
    at = np.arange(len(values), dtype=np.float64) if at is None else np.asarray(at, np.float64)
    count = len(values)
    if count <= 2 or tolerance <= 0:
        return np.arange(count)
    keep = np.zeros(count, bool)
    keep[[0, -1]] = True
    stack = [(0, count - 1)]
    while stack:
        low, high = stack.pop()
        if high - low < 2:
            continue
        inside = np.arange(low + 1, high)
        line = values[low] + (values[high] - values[low]) * (at[inside] - at[low]) / (at[high] - at[low])
        error = np.abs(values[inside] - line)
        worst = int(np.argmax(error))
        if error[worst] > tolerance:
            middle = int(inside[worst])
            keep[middle] = True
            stack += [(low, middle), (middle, high)]
    return np.nonzero(keep)[0]


def thinned(values: np.ndarray, tolerance: float) -> tuple[np.ndarray, int]:
    """``values (T,n)`` as their thinned keys play them back (linear between kept keys), and the keys kept."""
    values = np.asarray(values, np.float64).reshape(len(values), -1)
    out, keys = np.empty_like(values), 0
    steps = np.arange(len(values))
    for i in range(values.shape[1]):
        kept = thin_channel(values[:, i], tolerance)
        out[:, i] = np.interp(steps, kept, values[kept, i])
        keys += len(kept)
    return out, keys


def _tracked_params(capture: pathlib.Path, frames: int) -> dict[str, np.ndarray]:
    """The channels of a tracked capture's ``flame_param`` files, ``(T, n)`` each, every timestep
    (``Capture.flame_params_stacked`` reads only timesteps with a frame; lost ones have none)."""
    from ..data import layout
    from ..run.folder import load_flame_file

    files = [load_flame_file(capture / layout.flame_param_path(t)) for t in range(frames)]
    return {name: np.stack([np.asarray(f[name], np.float64).reshape(-1) for f in files]) for name in CHANNELS}


def performance_frames(performance: dict, lost: list[int], clip_fps: float, identity: Identity,
                       settings: DriveSettings) -> dict:
    """A tracked performance (``(T,n)`` per channel at ``clip_fps``) as the frames the avatar plays:
    put on its rest pose, retimed, thinned; with what ``drive.json`` says of it."""
    frames = len(performance["expr"])
    seen = np.ones(frames, bool)
    seen[[t for t in lost if t < frames]] = False
    placed = put_on_rest({name: performance[name] for name in CHANNELS}, identity.rest, seen,
                         settings.keep_head_still)
    fps = settings.fps or clip_fps
    params, keys = {}, 0
    for name in CHANNELS:
        params[name], kept = thinned(retime(placed[name], clip_fps, fps), settings.tolerance)
        keys += kept
    count = len(params["expr"])
    scale = (count - 1) / max(frames - 1, 1)
    return {"params": params, "frames": count, "fps": fps, "clip_fps": clip_fps, "tolerance": settings.tolerance,
            "keep_head_still": settings.keep_head_still, "keys": keys, "keys_dense": count * sum(
                params[name].shape[1] for name in CHANNELS),
            "lost_frames": sorted({int(round(t * scale)) for t in lost if t < frames})}


def write_performance(folder: pathlib.Path, params: dict, identity: Identity) -> int:
    """One ``{t:05d}.npz`` per frame: the performance on the avatar's identity."""
    from ..io.npz import save_npz

    folder.mkdir(parents=True, exist_ok=True)
    count = len(params["expr"])
    for t in range(count):
        frame = {name: params[name][t][None].astype(np.float32) for name in CHANNELS}
        frame["shape"] = identity.shape[None].astype(np.float32)
        if identity.static_offset is not None:
            frame["static_offset"] = identity.static_offset[None].astype(np.float32)
        save_npz(folder / f"{t:05d}.npz", frame)
    return count


def write_identity(path, shape, static_offset=None, rest: dict | None = None) -> None:
    """An identity file for :meth:`Identity.of`: a head's ``shape`` (and static offset), and the
    pose it rests in (``rotation``, ``neck_pose``, ``translation``): what a Blender head shows."""
    from ..io.npz import save_npz

    arrays = {"shape": np.asarray(shape, np.float64).reshape(-1)}
    if static_offset is not None:
        arrays["static_offset"] = np.asarray(static_offset, np.float64).reshape(-1, 3)
    for name in HEAD_MOTION:
        arrays[name] = np.asarray((rest or {}).get(name, np.zeros(3)), np.float64).reshape(3)
    save_npz(path, arrays)


def folder_beside(source, suffix: str) -> pathlib.Path:
    """A new folder's path beside the footage ``source``: ``clip_capture``, else ``clip_capture_2``, …
    (Blender's Track Footage and Drive from Footage write there unless told where)."""
    source = pathlib.Path(source)
    base = source.parent / f"{source.stem if source.is_file() else source.name}_{suffix}"
    candidate, number = base, 1
    while candidate.exists():
        number += 1
        candidate = base.with_name(f"{base.name}_{number}")
    return candidate
