"""Synthetic phone footage of the procedural head, with its truth written aside.

What a user would film to make an avatar: a handheld clip orbiting a still head, a clip from a still
camera while the head turns, or a few photos from around the head; the subject talks throughout
(the expression, speech and free sequences of :mod:`.sequences`, played at :data:`SCRIPT_RATE`).
Frames come from the independent mesh renderer (:mod:`.mesh_render`), as make-capture's do, then
get what a phone adds: auto exposure drifting, sensor noise, H.264 (or JPEG) compression.

Two folders: the footage folder holds only what a phone gives (``clip.mp4``, or the photos); the
truth folder holds the true FLAME parameters and camera of every frame, the script, and renders
from cameras the footage never saw. Tracking must never open the truth. See docs/tracking.md.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib

import numpy as np
import torch

from ..camera import Camera, focal_from_35mm
from ..errors import InputError
from ..flame.expression_roles import mouth_components
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel
from ..io.atomic import atomic_path, check_output_target, write_json
from ..io.image import to_uint8, write_png
from ..io.npz import save_npz
from ..io.video import APPLE_FOCAL_35MM, VideoWriter
from ..progress import ProgressBar
from . import layout
from .camera_file import write_cameras
from .footage_settings import FootageSettings
from .generator import BACKGROUND, params_at, write_head_model
from .mesh_render import render_mesh, vertex_normals
from .sequences import correlated_noise, expression_sequence, free_sequence, speech_sequence

FOOTAGE_DIR = "footage"
TRUTH_DIR = "truth"
CLIP_FILE = "clip.mp4"
INFO_FILE = "footage.json"
SCRIPT_FILE = "script.json"
CAMERAS_FILE = "cameras.json"
FLAME_DIR = "flame_param"
NOVEL_DIR = "novel_views"
SCRIPT_RATE = 10.0  # script timesteps a second: the speech sequence's syllables come 2–4 a second
# The script, repeated: (sequence, seconds). EXPRESSIONS moves a few components one after another.
SEGMENTS = (("SPEECH", 4.0), ("EXPRESSIONS", 3.0), ("SPEECH", 3.0), ("FREE", 3.0))
EXPRESSION_COMPONENTS = 6  # per EXPRESSIONS segment; the segments go through every component in turn
FADE_SECONDS = 0.3  # each segment starts and ends at rest (a pause between sentences)
CLIP_BACKGROUND = (0.56, 0.58, 0.6)  # a plain wall behind the subject
FACE_FILL = 0.6  # the head's width as a share of the image's shorter side
ORBIT_PERIOD = 8.0  # seconds for one sweep of the handheld camera (right, left, back)
TURN_PERIOD = 8.0  # seconds for one turn of the head left and right (fixed camera)
# Novel views (azimuth, elevation in degrees): outside every view the footage takes (|azimuth| ≤ 40°
# and |elevation| ≤ 12° for the camera; the head turning ±35° in front of a still camera).
NOVEL_PLACEMENTS = ((-70, 5), (70, 5), (0, 35), (0, -28), (-55, -22), (55, -22), (-60, 30), (60, 30),
                    (-90, 10), (90, 10), (-100, -5), (100, -5), (-35, 40), (35, 40), (-30, -35), (30, -35))
NOVEL_DISTANCE = 0.8  # metres
JPEG_QUALITY = 92
EXIF_ORIENTATION, EXIF_IFD, EXIF_FOCAL_35MM = 0x0112, 0x8769, 0xA405


@dataclasses.dataclass
class Script:
    """The performance at :data:`SCRIPT_RATE`: FLAME parameters ``(S, n)`` and what each segment does."""

    params: dict[str, np.ndarray]
    segments: list[dict]

    def at(self, seconds: float) -> dict[str, np.ndarray]:
        """The parameters at a time (linear between the script's timesteps)."""
        return params_at(self.params, seconds * SCRIPT_RATE)


def _fade(length: int) -> np.ndarray:
    ramp = max(1, round(FADE_SECONDS * SCRIPT_RATE))
    t = np.arange(length, dtype=np.float64)
    up = np.clip(t / ramp, 0, 1)
    down = np.clip((length - 1 - t) / ramp, 0, 1)
    return 0.5 - 0.5 * np.cos(np.pi * np.minimum(up, down))


def make_script(seconds: float, n_shape: int, n_expr: int, mouth: list[int], seed: int) -> Script:
    """The subject's performance for ``seconds``: :data:`SEGMENTS` repeated, each from the capture's
    sequence functions, its head motion left out (the footage moves the head or the camera itself)."""
    rng = np.random.default_rng([seed, 11])
    order = list(rng.permutation(n_expr))
    total = math.ceil(seconds * SCRIPT_RATE) + 2
    parts, segments, step, k = [], [], 0, 0
    while step < total:
        name, duration = SEGMENTS[k % len(SEGMENTS)]
        length = max(4, round(duration * SCRIPT_RATE))
        components = []
        if name == "SPEECH":
            raw = speech_sequence(rng, length, list(mouth), n_expr)
            components = [int(c) for c in mouth]
        elif name == "EXPRESSIONS":
            components = [int(order[(len(segments) * EXPRESSION_COMPONENTS + j) % n_expr])
                          for j in range(min(EXPRESSION_COMPONENTS, n_expr))]
            raw = expression_sequence(rng, length, components, n_expr, with_jaw=k % 8 >= 4)
        else:
            raw = free_sequence(rng, length, n_expr)
        window = _fade(length)[:, None]
        parts.append({key: np.asarray(raw[key]) * window for key in ("expr", "jaw_pose", "eyes_pose")})
        segments.append({"sequence": name, "start": step / SCRIPT_RATE, "end": (step + length) / SCRIPT_RATE,
                         **({"components": components} if components else {})})
        step += length
        k += 1
    params = {key: np.concatenate([p[key] for p in parts]) for key in ("expr", "jaw_pose", "eyes_pose")}
    steps = len(params["expr"])
    params.update({"shape": np.zeros((steps, n_shape)), "rotation": np.zeros((steps, 3)),
                   "neck_pose": np.zeros((steps, 3)), "translation": np.zeros((steps, 3))})
    return Script({key: value.astype(np.float32) for key, value in params.items()}, segments)


def _sine(t, period, phase=0.0):
    return np.sin(2 * np.pi * np.asarray(t) / period + phase)


def _rotate_camera(camera: Camera, rotvec, shift=(0.0, 0.0, 0.0)) -> Camera:
    """Turn a camera about its own centre by ``rotvec`` (camera axes, radians) and move it by ``shift``."""
    delta = np.eye(4)
    delta[:3, :3] = axis_angle_to_matrix(torch.tensor(np.asarray(rotvec, dtype=np.float64))).numpy()
    delta[:3, 3] = shift
    return dataclasses.replace(camera, w2c=delta @ camera.w2c)


class FootageScene:
    """Everything one footage shows, frame by frame: the script, the head's pose, the cameras, the
    exposure; :meth:`image` renders frame ``i`` as the phone records it (before compression)."""

    def __init__(self, settings: FootageSettings, model: FlameModel):
        settings.check()
        self.settings = s = settings
        self.model = model
        arrays = model.arrays
        if arrays.vt is None or arrays.texture is None:
            raise InputError(None, "vt/ft/texture", "synthetic footage needs a model with UVs and a texture")
        self.texture = arrays.texture.astype(np.float32) / 255.0
        with torch.no_grad():
            rest = model()[0].double().numpy()
        low, high = rest.min(0), rest.max(0)
        self.target = np.array([0.5 * (low[0] + high[0]), high[1] - 0.4 * (high[1] - low[1]), 0.5 * (low[2] + high[2])])
        self.head_width = float(high[0] - low[0])
        self.head_extent = float(np.max(high - low))
        self.count = s.frame_count
        if s.kind == "photos":
            self.times = (np.arange(self.count) + 0.5) * s.seconds / self.count
        else:
            self.times = np.arange(self.count) / s.fps
        self.script = make_script(float(self.times[-1]) + 1.0 / SCRIPT_RATE, model.n_shape, model.n_expr,
                                  mouth_components(arrays), seed=s.seed + 7919 * s.subject)
        rng = np.random.default_rng([s.seed, s.subject, 41])
        self.sizes = self._frame_sizes()
        self.cameras = self._cameras(rng)
        self.head = self._head_motion(rng)
        if s.kind == "photos":
            self.gains = np.exp(s.exposure_drift * rng.normal(size=self.count))
        else:
            self.gains = np.exp(s.exposure_drift * correlated_noise(rng, self.count, 1, 1.5 * s.fps)[:, 0])
        self.novel_cameras = self._novel_cameras()
        every = 1 if s.kind == "photos" else s.novel_every
        self.novel_frames = list(range(0, self.count, every)) if self.novel_cameras else []

    # -- what the footage shows ----------------------------------------------------------------

    def _frame_sizes(self) -> list[tuple[int, int, int]]:
        """Upright ``(width, height, EXIF orientation)`` per frame: photos mix a portrait stored
        landscape with its orientation tag (as phones store them), a landscape shot, and a smaller copy."""
        s = self.settings
        if s.kind != "photos":
            return [(s.width, s.height, 1)] * self.count
        sizes = []
        for k in range(self.count):
            if k % 3 == 0:
                sizes.append((s.width, s.height, 6))
            elif k % 3 == 1:
                sizes.append((s.height, s.width, 1))
            else:
                sizes.append((2 * round(0.375 * s.width), 2 * round(0.375 * s.height), 1))
        return sizes

    def _intrinsics(self, rng, width, height) -> dict:
        focal = focal_from_35mm(self.settings.focal_35mm, width, height)
        return {"fx": focal, "fy": focal, "cx": width / 2 + rng.normal(scale=0.004 * width),
                "cy": height / 2 + rng.normal(scale=0.004 * height)}

    def _cameras(self, rng) -> list[Camera]:
        s, t, n = self.settings, self.times, self.count
        base_w, base_h = s.width, s.height
        distance = focal_from_35mm(s.focal_35mm, base_w, base_h) * self.head_width / (FACE_FILL * min(base_w, base_h))
        self.distance = distance
        intrinsics = self._intrinsics(rng, base_w, base_h)
        if s.kind == "fixed":
            azimuth, elevation = np.zeros(n), np.full(n, 3.0)
            distances = np.full(n, 1.15 * distance)
        elif s.kind == "handheld":
            phases = rng.uniform(0, 2 * np.pi, size=2)
            azimuth = s.orbit * _sine(t, ORBIT_PERIOD)
            elevation = 4.0 + 6.0 * _sine(t, 13.0, phases[0])
            distances = distance * (1 + 0.04 * _sine(t, 7.0, phases[1]))
        else:  # photos: from around the head, in order, each a little off
            azimuth = np.linspace(-s.orbit, s.orbit, n) if n > 1 else np.zeros(1)
            elevation = rng.uniform(-8.0, 12.0, size=n)
            distances = distance * rng.uniform(0.95, 1.08, size=n)
        if s.kind == "handheld":  # the hand: aim wandering slowly, tremor, the phone's roll
            aim = 0.01 * s.shake * correlated_noise(rng, n, 3, 1.0 * s.fps)
            tremor = np.radians(0.25) * s.shake * correlated_noise(rng, n, 3, 2.0)
            roll = np.radians(2.0) * s.shake * correlated_noise(rng, n, 1, 1.5 * s.fps)[:, 0]
            shift = 0.002 * s.shake * correlated_noise(rng, n, 3, 3.0)
        else:
            aim, tremor, roll, shift = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3))
        cameras = []
        for i in range(n):
            width, height, _ = self.sizes[i]
            own = intrinsics if (width, height) == (base_w, base_h) else self._scaled(intrinsics, width, height)
            if (width, height) == (base_h, base_w) and base_h > base_w:  # a landscape photo: a step back
                distances[i] *= base_h / base_w
            az, el = np.radians(azimuth[i]), np.radians(elevation[i])
            direction = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
            camera = Camera.look_at(self.target + distances[i] * direction, self.target + aim[i], width=width,
                                    height=height, camera_id=f"{i:05d}", **own)
            cameras.append(_rotate_camera(camera, tremor[i] + np.array([0.0, 0.0, roll[i]]), shift[i]))
        return cameras

    def _scaled(self, intrinsics, width, height) -> dict:
        """The same lens at another size: a photo turned landscape (same focal length, principal
        point kept relative to the centre) or scaled down (everything scaled)."""
        s = self.settings
        if (width, height) == (s.height, s.width):
            return {**intrinsics, "cx": width / 2 + (intrinsics["cy"] - s.height / 2),
                    "cy": height / 2 + (intrinsics["cx"] - s.width / 2)}
        scale = width / s.width
        return {key: value * scale for key, value in intrinsics.items()}

    def _head_motion(self, rng) -> dict[str, np.ndarray]:
        """The head's rotation (axis-angle: pitch, yaw, roll) and translation per frame: turning and
        nodding in front of a fixed camera, still otherwise."""
        s, t, n = self.settings, self.times, self.count
        if s.kind != "fixed":
            return {"rotation": np.zeros((n, 3), np.float32), "translation": np.zeros((n, 3), np.float32)}
        phases = rng.uniform(0, 2 * np.pi, size=6)
        yaw = np.radians(s.head_yaw) * _sine(t, TURN_PERIOD)
        pitch = np.radians(s.head_pitch) * _sine(t, 5.3, phases[0])
        roll = np.radians(3.0) * _sine(t, 11.0, phases[1])
        translation = np.stack([0.006 * _sine(t, 9.0, phases[2]), 0.003 * _sine(t, 6.0, phases[3]),
                                0.01 * _sine(t, 12.0, phases[4])], 1)
        return {"rotation": np.stack([pitch, yaw, roll], 1).astype(np.float32),
                "translation": translation.astype(np.float32)}

    def _novel_cameras(self) -> list[Camera]:
        s = self.settings
        size = s.novel_size
        fx = 0.85 * size * NOVEL_DISTANCE / self.head_extent
        cameras = []
        for k, (azimuth, elevation) in enumerate(NOVEL_PLACEMENTS[: s.novel_views]):
            az, el = np.radians(azimuth), np.radians(elevation)
            direction = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
            cameras.append(Camera.look_at(self.target + NOVEL_DISTANCE * direction, self.target, width=size,
                                          height=size, fx=fx, camera_id=f"novel{k:02d}"))
        return cameras

    # -- frames ---------------------------------------------------------------------------------

    def params(self, i: int) -> dict[str, np.ndarray]:
        """The true FLAME parameters of frame ``i`` (each ``(n,)`` float32)."""
        params = self.script.at(float(self.times[i]))
        params["rotation"] = self.head["rotation"][i].copy()
        params["translation"] = self.head["translation"][i].copy()
        return params

    def mesh(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and their normals at frame ``i``."""
        posed = self.model.posed(self.params(i))
        return posed, vertex_normals(posed, self.model.arrays.faces)

    def render(self, mesh, camera: Camera, background) -> tuple[np.ndarray, np.ndarray]:
        arrays = self.model.arrays
        vertices, normals = mesh
        return render_mesh(vertices, arrays.faces, arrays.vt, arrays.ft, self.texture, camera, background,
                           supersample=self.settings.supersample, normals=normals)

    def image(self, i: int, mesh=None) -> np.ndarray:
        """Frame ``i`` as the phone's sensor gives it: upright RGB ``uint8``, exposure and noise applied."""
        rgb, _ = self.render(self.mesh(i) if mesh is None else mesh, self.cameras[i], CLIP_BACKGROUND)
        rgb = rgb * np.float32(self.gains[i])
        if self.settings.sensor_noise:
            noise = np.random.default_rng([self.settings.seed, self.settings.subject, 5, i])
            rgb = rgb + noise.normal(scale=self.settings.sensor_noise / 255.0, size=rgb.shape).astype(np.float32)
        return to_uint8(rgb)


# -- writing ---------------------------------------------------------------------------------------


@dataclasses.dataclass
class FootageFolders:
    footage: pathlib.Path  # what a phone gives: the clip, or the photos
    truth: pathlib.Path  # never opened by tracking
    files: list[pathlib.Path]  # the footage folder's files


def _empty_folder(path: pathlib.Path, what: str) -> None:
    check_output_target(path, folder=True)
    if path.exists() and any(path.iterdir()):
        raise InputError(path, None, f"is not empty; the {what} is written into a new or empty folder")


def _photo_exif(orientation: int, focal_35mm: float | None):
    from PIL import Image

    exif = Image.Exif()
    exif[EXIF_ORIENTATION] = orientation
    if focal_35mm:
        exif.get_ifd(EXIF_IFD)[EXIF_FOCAL_35MM] = int(round(focal_35mm))
    return exif


def write_photo(path, upright: np.ndarray, orientation: int, focal_35mm: float | None) -> None:
    """A JPEG as a phone writes it: stored so that its EXIF ``orientation`` shows it ``upright``."""
    from PIL import Image

    stored = {1: upright, 6: np.rot90(upright, 1)}[orientation]
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(stored)).save(tmp, format="JPEG", quality=JPEG_QUALITY,
                                                           exif=_photo_exif(orientation, focal_35mm))


def _write_flame(path: pathlib.Path, params: dict[str, np.ndarray]) -> None:
    save_npz(path, layout.batched_flame_params(layout.normalize_flame_params(params, path)))


def make_footage(out: str | os.PathLike, settings: FootageSettings = FootageSettings(),
                 truth: str | os.PathLike | None = None, model_path: str | os.PathLike | None = None,
                 progress: bool = True) -> FootageFolders:
    """Render footage into ``out/footage`` and its truth into ``truth`` (default ``out/truth``)."""
    settings.check()
    out = pathlib.Path(out)
    footage_dir = out / FOOTAGE_DIR
    truth_dir = pathlib.Path(truth) if truth is not None else out / TRUTH_DIR
    if truth_dir.resolve().is_relative_to(footage_dir.resolve()):
        raise InputError(truth_dir, None, f"the truth must lie outside the footage folder {footage_dir}")
    _empty_folder(footage_dir, "footage")
    _empty_folder(truth_dir, "truth")
    truth_dir.mkdir(parents=True, exist_ok=True)
    head_file = write_head_model(truth_dir, settings.subject, settings.seed, model_path)
    scene = FootageScene(settings, FlameModel.load(head_file))
    footage_dir.mkdir(parents=True, exist_ok=True)

    novel_total = len(scene.novel_frames) * len(scene.novel_cameras)
    bar = ProgressBar(scene.count + novel_total, "make-footage") if progress else None
    focal = settings.focal_35mm if settings.lens_metadata else None
    novel = set(scene.novel_frames)
    files, photos = [], []

    def frame_done(i: int, mesh) -> None:
        _write_flame(truth_dir / FLAME_DIR / f"{i:05d}.npz", scene.params(i))
        if i in novel:
            for camera in scene.novel_cameras:
                rgb, alpha = scene.render(mesh, camera, BACKGROUND)
                write_png(truth_dir / NOVEL_DIR / "images" / f"{i:05d}_{camera.camera_id}.png", rgb)
                write_png(truth_dir / NOVEL_DIR / "masks" / f"{i:05d}_{camera.camera_id}.png", alpha)
                if bar:
                    bar.update()
        if bar:
            bar.update()

    if settings.kind == "photos":
        for i in range(scene.count):
            mesh = scene.mesh(i)
            width, height, orientation = scene.sizes[i]
            path = footage_dir / f"IMG_{i + 1:04d}.jpg"
            write_photo(path, scene.image(i, mesh), orientation, focal)
            files.append(path)
            photos.append({"file": path.name, "width": width, "height": height, "orientation": orientation,
                           "exposure_gain": float(scene.gains[i])})
            frame_done(i, mesh)
    else:
        clip = footage_dir / CLIP_FILE
        metadata = {APPLE_FOCAL_35MM: f"{settings.focal_35mm:g}"} if focal else None
        with VideoWriter(clip, settings.width, settings.height, settings.fps, crf=settings.crf,
                         rotation_flag=settings.rotation_flag, metadata=metadata) as video:
            for i in range(scene.count):
                mesh = scene.mesh(i)
                video.write(scene.image(i, mesh))
                frame_done(i, mesh)
        files.append(clip)

    write_cameras(truth_dir / CAMERAS_FILE, {c.camera_id: c for c in scene.cameras})
    if scene.novel_cameras:
        write_cameras(truth_dir / NOVEL_DIR / CAMERAS_FILE, {c.camera_id: c for c in scene.novel_cameras})
    write_json(truth_dir / SCRIPT_FILE, {
        "script_rate": SCRIPT_RATE,
        "segments": scene.script.segments,
        "head": ("turning: rotation = (pitch, yaw, roll) axis-angle, yaw ±{:g}°, pitch ±{:g}°".format(
            settings.head_yaw, settings.head_pitch) if settings.kind == "fixed" else "still"),
        "camera": {"handheld": f"orbiting ±{settings.orbit:g}° with hand shake", "fixed": "still",
                   "photos": f"one view a photo, from -{settings.orbit:g}° to +{settings.orbit:g}°"}[settings.kind],
    })
    info = {
        "generator": "mogaface make-footage",
        "settings": dataclasses.asdict(settings),
        "footage": [p.name for p in files],
        "model_file": head_file.name,
        "frames": scene.count,
        "times": [float(t) for t in scene.times] if settings.kind != "photos" else None,
        "exposure_gain": [float(g) for g in scene.gains],
        "background": list(CLIP_BACKGROUND),
        "focal_px": focal_from_35mm(settings.focal_35mm, settings.width, settings.height),
        "flame_param": f"{FLAME_DIR}/{{frame:05d}}.npz",
        "cameras": CAMERAS_FILE,
        "script": SCRIPT_FILE,
        "novel_views": {
            "cameras": f"{NOVEL_DIR}/{CAMERAS_FILE}" if scene.novel_cameras else None,
            "frames": scene.novel_frames,
            "images": f"{NOVEL_DIR}/images/{{frame:05d}}_{{camera}}.png",
            "masks": f"{NOVEL_DIR}/masks/{{frame:05d}}_{{camera}}.png",
            "background": list(BACKGROUND),
        },
        **({"photos": photos} if photos else {}),
    }
    write_json(truth_dir / INFO_FILE, info)  # last: a truth folder with it is complete
    return FootageFolders(footage_dir, truth_dir, files)
