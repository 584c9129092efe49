"""Blender-free conversions between the project's data and a Blender scene.

The Blender layer (``operators/``) reads and writes Blender data; everything it needs to
compute lives here, in numpy, so it is testable without Blender:

- the one axis conversion (FLAME/OpenCV world, y up → Blender world, z up);
- a capture camera → Blender camera settings (lens, shifts, pixel aspect, pose);
- timesteps ↔ scene frames;
- the head rig: basis and expression shape keys, and the "pose" shape key that makes
  Blender's shape-key blend equal the core's FLAME evaluation (pose correctives, skinning);
- tracked FLAME parameters of a ``flame_param`` folder as keyframe columns.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re
import threading

import numpy as np

from .camera import Camera
from .data.capture import Capture
from .errors import InputError

# -- axes ---------------------------------------------------------------------------------------

#: FLAME world (y up, z toward the face's front) → Blender world (z up): +90° about x, so
#: FLAME +y → Blender +z and FLAME +z (the face's front) → Blender −y (the usual front view).
FLAME_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# OpenCV camera axes (x right, y down, z forward) ↔ Blender camera axes (x right, y up, z back).
_CV_TO_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])


def flame_to_blender(points) -> np.ndarray:
    """Points or directions ``(…,3)`` in FLAME world axes → Blender world axes (float64).

    The single place where the project's y-up world meets Blender's z-up world; every
    position that crosses into Blender (mesh vertices, shape keys, cameras) goes through it.
    """
    return np.asarray(points, dtype=np.float64) @ FLAME_TO_BLENDER.T


def blender_to_flame(points) -> np.ndarray:
    """The inverse of :func:`flame_to_blender`."""
    return np.asarray(points, dtype=np.float64) @ FLAME_TO_BLENDER


def flame_to_blender_matrix(matrix) -> np.ndarray:
    """A 4×4 transform whose output is in FLAME world → the same transform into Blender world."""
    world = np.eye(4)
    world[:3, :3] = FLAME_TO_BLENDER
    return world @ np.asarray(matrix, dtype=np.float64)


# -- timeline -----------------------------------------------------------------------------------

#: Blender's timeline starts at frame 1: timestep ``t`` is shown on frame ``t + FRAME_OFFSET``.
FRAME_OFFSET = 1


def timestep_to_frame(timestep: int) -> int:
    """The scene frame that shows capture/tracking timestep ``timestep``."""
    return int(timestep) + FRAME_OFFSET


def frame_to_timestep(frame: int) -> int:
    """The timestep shown on scene frame ``frame``."""
    return int(frame) - FRAME_OFFSET


# -- cameras ------------------------------------------------------------------------------------

SENSOR_WIDTH_MM = 36.0


@dataclasses.dataclass
class BlenderCamera:
    """Everything a Blender camera needs to image exactly like one capture camera.

    ``lens``/``sensor_width`` in mm with ``sensor_fit='HORIZONTAL'``; shifts in units of the
    image width; ``pixel_aspect`` (x, y) for fx ≠ fy (both ≥ 1, as Blender requires);
    ``matrix_world`` 4×4 in Blender world axes; ``image_path`` of its first view, if any.
    """

    name: str
    camera_id: str
    lens: float
    sensor_width: float
    shift_x: float
    shift_y: float
    resolution: tuple[int, int]
    pixel_aspect: tuple[float, float]
    matrix_world: np.ndarray
    image_path: str | None = None
    sensor_fit: str = "HORIZONTAL"


def blender_camera(camera: Camera, name: str | None = None, image_path=None) -> BlenderCamera:
    """A capture :class:`~mogaface.core.camera.Camera` (OpenCV ``K``, ``w2c``) as Blender settings.

    Blender's view plane (horizontal sensor fit) spans ``sensor_width`` across the image
    width, so ``fx = lens·W/sensor_width``; pixel rows are ``pixel_aspect_y/pixel_aspect_x``
    times taller than columns are wide, so that ratio is ``fx/fy``; the shifts move the
    frame's centre away from the optical axis in units of the width.
    """
    width, height = camera.width, camera.height
    ratio = camera.fx / camera.fy  # pixel_aspect_y / pixel_aspect_x
    aspect = (1.0, ratio) if ratio >= 1.0 else (1.0 / ratio, 1.0)
    c2w_blender_camera = np.linalg.inv(camera.w2c) @ _CV_TO_BLENDER_CAMERA
    return BlenderCamera(
        name=name or f"Camera {camera.camera_id}",
        camera_id=camera.camera_id,
        lens=camera.fx * SENSOR_WIDTH_MM / width,
        sensor_width=SENSOR_WIDTH_MM,
        shift_x=-(camera.cx - 0.5 * width) / width,
        shift_y=(camera.cy - 0.5 * height) / width * ratio,
        resolution=(width, height),
        pixel_aspect=aspect,
        matrix_world=flame_to_blender_matrix(c2w_blender_camera),
        image_path=None if image_path is None else os.fspath(image_path),
    )


@dataclasses.dataclass
class CaptureScene:
    """A capture as Blender sees it: its cameras (with first-view images) and its frame range."""

    root: str
    cameras: list[BlenderCamera]
    frame_start: int
    frame_end: int
    n_timesteps: int
    # Camera ids whose pose differs between frames (a union of sequences: VHAP moves each
    # sequence's cameras); they are imported at the pose of their first frame.
    moving_cameras: list[str] = dataclasses.field(default_factory=list)


def capture_scene(folder, refined_cameras=None) -> CaptureScene:
    """Open a capture folder and describe its Blender scene (cameras, images, timeline).

    Each camera's background image is its view at the first timestep it was captured in.
    ``refined_cameras``: a run's ``cameras_refined.json`` (camera refinement); the cameras it
    names take its poses, the others (the held-out camera) keep the capture's.
    Raises :class:`~mogaface.core.errors.CaptureError` naming the file of the first problem.
    """
    capture = Capture.open(folder)
    refined = _refined_poses(capture, refined_cameras)
    first_frame = {}
    for frame in sorted(capture.frames(), key=lambda f: (f.timestep_index, f.camera_index)):
        first_frame.setdefault(frame.camera_id, frame)
    cameras = []
    for camera_id, camera in capture.cameras.items():
        frame = first_frame.get(camera_id)
        image = capture.path(frame, "file_path") if frame is not None else None
        pose = refined.get(camera_id) or (capture.camera(frame) if frame is not None else camera)
        cameras.append(blender_camera(pose, f"Camera {camera_id}", image))
    moving = sorted({f.camera_id for f in capture.frames() if f.camera_id not in refined
                     if not np.allclose(capture.camera(f).w2c, capture.camera(first_frame[f.camera_id]).w2c)})
    return CaptureScene(
        root=os.fspath(capture.root),
        cameras=cameras,
        frame_start=timestep_to_frame(min(capture.timesteps)),
        frame_end=timestep_to_frame(max(capture.timesteps)),
        n_timesteps=len(capture.timesteps),
        moving_cameras=moving,
    )


def _refined_poses(capture: Capture, path) -> dict[str, Camera]:
    """The refined cameras of ``path`` (none when ``path`` is empty), checked against the capture."""
    if not path:
        return {}
    from .evaluate.images import read_cameras

    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError(path, None, "refined cameras file not found")
    refined = read_cameras(path)
    unknown = sorted(set(refined) - set(capture.cameras))
    if unknown:
        raise InputError(path, unknown[0], f"camera id not in the capture {capture.root} "
                                           f"(known: {', '.join(sorted(capture.cameras))})")
    return refined


# -- images -------------------------------------------------------------------------------------


def image_pixels(image) -> np.ndarray:
    """An ``(H,W,3|4)`` image (uint8, or float in [0,1]) → Blender's flat RGBA float32 pixels.

    Blender stores rows bottom to top; our images are top to bottom.
    """
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] not in (3, 4):
        raise InputError(None, "texture", f"expected an (H, W, 3|4) image, found shape {array.shape}")
    values = array.astype(np.float32) / 255.0 if array.dtype == np.uint8 else array.astype(np.float32)
    if values.shape[2] == 3:
        values = np.concatenate([values, np.ones(values.shape[:2] + (1,), np.float32)], axis=2)
    return np.ascontiguousarray(values[::-1]).reshape(-1)


# -- the head rig -------------------------------------------------------------------------------

#: Object custom properties that hold the pose, with their sizes (FLAME's parameter names).
POSE_PROPERTIES = {
    "rotation": ("mogaface_rotation", 3),
    "neck_pose": ("mogaface_neck_pose", 3),
    "jaw_pose": ("mogaface_jaw_pose", 3),
    "eyes_pose": ("mogaface_eyes_pose", 6),
    "translation": ("mogaface_translation", 3),
}
MODEL_PATH_PROPERTY = "mogaface_model_path"
SHAPE_PROPERTY = "mogaface_shape"
STATIC_OFFSET_PROPERTY = "mogaface_static_offset"
POSE_KEY_NAME = "MoGaFace pose"
EXPRESSION_SLIDER_RANGE = 10.0

_model_cache: dict = {}
_model_cache_lock = threading.Lock()


def _file_version(path, what: str) -> tuple[pathlib.Path, tuple]:
    """The resolved path and a cache key that changes whenever the file is rewritten."""
    path = pathlib.Path(path).expanduser().resolve()
    try:
        stat = path.stat()
    except OSError:
        raise InputError(path, None, f"{what} file not found") from None
    return path, (os.fspath(path), stat.st_size, stat.st_mtime_ns)


def load_head_model(path, n_vertices: int | None = None):
    """The :class:`~mogaface.core.flame.numpy_model.NumpyFlame` of ``path``, cached per file.

    numpy, not torch: importing and posing heads in Blender needs no torch. The cache key
    includes the file's size and modification time, so an edited file reloads.
    ``n_vertices``: a tracking's vertex count (5143 on FLAME adds its teeth, see ``flame.teeth``).
    """
    from .flame.numpy_model import NumpyFlame

    path, key = _file_version(path, "head model")
    key = key + (n_vertices,)
    with _model_cache_lock:
        model = _model_cache.get(key)
        if model is None:
            model = NumpyFlame.load(path, n_vertices=n_vertices)
            for old in [k for k in _model_cache if k[0] == key[0] and k[-1] == n_vertices]:
                del _model_cache[old]
            _model_cache[key] = model
    return model


def identity_vertex_count(path) -> int | None:
    """The vertex count of an ``.npz``'s ``static_offset`` (None without one)."""
    from .io.npz import load_npz

    offset = load_npz(path).get("static_offset")
    return None if offset is None or np.ndim(offset) < 2 else int(np.shape(offset)[-2])


def read_identity(path, n_shape: int, n_vertices: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``shape`` (fitted to ``n_shape``) and ``static_offset`` (or None) from an ``.npz``.

    Any file with a ``shape`` array works: a ``flame_param`` timestep, the canonical file, or
    one holding only the identity.
    """
    from .io.npz import load_npz

    params = load_npz(path)
    if "shape" not in params:
        raise InputError(path, "shape", f"missing (the file has {sorted(params)})")
    shape = np.asarray(params["shape"])
    if shape.ndim == 2 and shape.shape[0] == 1:
        shape = shape[0]
    if shape.ndim != 1 or shape.dtype.kind not in "fiu" or not np.isfinite(shape).all():
        raise InputError(path, "shape", f"expected a finite (n,) or (1, n) array, found {shape.shape} {shape.dtype}")
    offset = params.get("static_offset")
    if offset is not None:
        offset = np.asarray(offset, np.float64)
        offset = offset[0] if offset.ndim == 3 and offset.shape[0] == 1 else offset
        if offset.shape != (n_vertices, 3) or not np.isfinite(offset).all():
            problem = f"expected shape ({n_vertices}, 3) for this head, found {offset.shape}"
            raise InputError(path, "static_offset", problem)
    return fit_components(shape, n_shape), offset


def fit_components(values, count: int) -> np.ndarray:
    """Coefficients ``(…, n)`` padded with zeros or cut to ``count`` (FLAME uses the leading ones)."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1] >= count:
        return values[..., :count].copy()
    pad = [(0, 0)] * (values.ndim - 1) + [(0, count - values.shape[-1])]
    return np.pad(values, pad)


@dataclasses.dataclass
class HeadRig:
    """A FLAME head as Blender shows it: shape keys for expressions, a pose key for the rest.

    Blender's relative shape keys give ``basis + Σ wₖ (keyₖ − basis)``. The basis is the
    identity's neutral head, key k adds expression component k, and the pose key (weight 1)
    adds ``posed − unposed``: the pose correctives, skinning and translation that FLAME
    applies on top of the blend shapes. Blender's blend then equals the core's evaluation.
    All positions are in Blender world axes (see :func:`flame_to_blender`).
    """

    model: object  # NumpyFlame
    shape: np.ndarray
    static_offset: np.ndarray | None = None

    def __post_init__(self):
        self.shape = fit_components(self.shape, self.model.n_shape)

    def neutral(self) -> np.ndarray:
        """The identity's head without expression or pose, FLAME axes ``(V,3)``."""
        arrays = self.model.arrays
        out = arrays.v_template + arrays.shapedirs @ self.shape
        return out if self.static_offset is None else out + self.static_offset

    def basis(self) -> np.ndarray:
        return flame_to_blender(self.neutral())

    def expression_keys(self) -> np.ndarray:
        """``(n_expr, V, 3)``: the basis plus one expression component each (Blender axes)."""
        exprdirs = np.moveaxis(self.model.arrays.exprdirs, 2, 0)
        return self.basis()[None] + flame_to_blender(exprdirs)

    def evaluate(self, expr, pose: dict) -> np.ndarray:
        """The core's FLAME evaluation for this identity, FLAME axes ``(V,3)`` float64."""
        return self.model(shape=self.shape, expr=fit_components(expr, self.model.n_expr),
                          static_offset=self.static_offset, **pose)

    def pose_key(self, expr, pose: dict) -> np.ndarray:
        """The pose shape key for expression weights ``expr`` and ``pose`` (Blender axes)."""
        expr = fit_components(expr, self.model.n_expr)
        unposed = self.neutral() + self.model.arrays.exprdirs @ expr
        return self.basis() + flame_to_blender(self.evaluate(expr, pose) - unposed)


def zero_pose() -> dict:
    """Every pose parameter at rest (FLAME names)."""
    return {name: np.zeros(size) for name, (_, size) in POSE_PROPERTIES.items()}


@dataclasses.dataclass
class HeadImport:
    """What Blender needs to build a head object: mesh, UVs, texture, shape keys, rig."""

    name: str
    model_path: str
    rig: HeadRig
    faces: np.ndarray  # (F,3) vertex indices, the model's triangle order
    basis: np.ndarray  # (V,3) Blender axes
    expression_keys: np.ndarray  # (n_expr,V,3)
    expression_names: list
    pose_key: np.ndarray  # (V,3) at the rest pose
    loop_uvs: np.ndarray | None  # (3F,2) one UV per triangle corner
    texture_pixels: np.ndarray | None  # flat RGBA float32, Blender row order
    texture_size: tuple[int, int] | None  # (width, height)


def head_import(path, shape_file=None) -> HeadImport:
    """Load a FLAME-format head (and optionally the identity of a ``flame_param`` npz) for Blender."""
    model = load_head_model(path, identity_vertex_count(shape_file) if shape_file else None)
    arrays = model.arrays
    if shape_file:
        shape, offset = read_identity(shape_file, model.n_shape, model.n_vertices)
    else:
        shape, offset = np.zeros(model.n_shape), None
    rig = HeadRig(model, shape, offset)
    uvs = None if arrays.vt is None else arrays.vt[arrays.ft].reshape(-1, 2)
    texture = arrays.texture
    return HeadImport(
        name=pathlib.Path(path).stem,
        model_path=os.fspath(pathlib.Path(path).expanduser().resolve()),
        rig=rig,
        faces=np.asarray(arrays.faces, np.int64),
        basis=rig.basis(),
        expression_keys=rig.expression_keys(),
        expression_names=list(model.expression_names),
        pose_key=rig.pose_key(np.zeros(model.n_expr), zero_pose()),
        loop_uvs=uvs,
        texture_pixels=None if texture is None else image_pixels(texture),
        texture_size=None if texture is None else (texture.shape[1], texture.shape[0]),
    )


# -- tracking -----------------------------------------------------------------------------------


@dataclasses.dataclass
class Tracking:
    """Tracked FLAME parameters of a ``flame_param`` folder, one row per timestep."""

    folder: str
    timesteps: np.ndarray  # (T,) int
    params: dict  # name -> (T, n) float64: expr and the POSE_PROPERTIES names

    @property
    def frames(self) -> np.ndarray:
        return self.timesteps + FRAME_OFFSET


_DIGITS = re.compile(r"(\d+)$")


def read_tracking(folder) -> Tracking:
    """Read every ``*.npz`` of a ``flame_param`` folder (VHAP/GaussianAvatars layout).

    The timestep of ``00042.npz`` is 42 (the trailing digits of the name); files without
    digits take their position in name order. Only expression and pose are read: the
    identity (``shape``) belongs to the head they are applied to.
    """
    from .data import layout
    from .io.npz import load_npz

    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise InputError(folder, None, "not a folder (expected a flame_param folder of .npz files)")
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise InputError(folder, None, "no .npz files (expected a flame_param folder)")
    numbered = [_DIGITS.search(f.stem) for f in files]
    if all(numbered):
        timesteps = np.array([int(m.group(1)) for m in numbered])
        order = np.argsort(timesteps, kind="stable")
        files, timesteps = [files[i] for i in order], timesteps[order]
        if len(set(timesteps.tolist())) != len(timesteps):
            raise InputError(folder, None, "two files name the same timestep")
    else:
        timesteps = np.arange(len(files))
    names = ["expr", *POSE_PROPERTIES]
    rows = {name: [] for name in names}
    for path in files:
        params = layout.normalize_flame_params(load_npz(path), path)
        if "dynamic_offset" in params and np.abs(params["dynamic_offset"]).max() > 0:
            raise InputError(path, "dynamic_offset",
                             "per-timestep vertex offsets (VHAP's use_dynamic_offset) cannot be keyed as shape-key "
                             "values in Blender; render such tracking with 'python -m mogaface render', or track "
                             "without dynamic offsets")
        for name in names:
            if name not in params:
                raise InputError(path, name, "missing from the tracked parameters")
            rows[name].append(np.asarray(params[name], np.float64).reshape(-1))
    out = {}
    for name, values in rows.items():
        sizes = {len(v) for v in values}
        if len(sizes) != 1:
            raise InputError(folder, name, f"sizes differ between files: {sorted(sizes)}")
        out[name] = np.stack(values)
    return Tracking(os.fspath(folder), timesteps, out)


def keyframe_columns(frames, values) -> list[np.ndarray]:
    """``values (T,n)`` at ``frames (T,)`` → n flat ``[f0, v0, f1, v1, …]`` float32 arrays.

    The layout of ``FCurve.keyframe_points.foreach_set("co", …)``: one array per channel.
    """
    frames = np.asarray(frames, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64).reshape(len(frames), -1)
    return [np.ascontiguousarray(np.stack([frames, values[:, i]], axis=1), dtype=np.float32).reshape(-1)
            for i in range(values.shape[1])]


def expression_keyframes(tracking: Tracking, n_expr: int) -> tuple[np.ndarray, str | None]:
    """The tracked expressions fitted to a head with ``n_expr`` keys, plus a warning if cut.

    Coefficients beyond the head's count are dropped (reported); missing ones are zero. Values
    outside the shape-key slider range are clamped by Blender, so they are reported too.
    """
    expr = tracking.params["expr"]
    notes = []
    if expr.shape[1] > n_expr:
        notes.append(f"the tracking has {expr.shape[1]} expression components, the head {n_expr}: extra ones ignored")
    fitted = fit_components(expr, n_expr)
    if np.abs(fitted).max(initial=0.0) > EXPRESSION_SLIDER_RANGE:
        notes.append(f"expression values beyond ±{EXPRESSION_SLIDER_RANGE:g} are clamped by Blender's sliders")
    return fitted, "; ".join(notes) or None


@dataclasses.dataclass
class TrackingChannels:
    """Keyframe columns for one head: per pose property its channels, per expression key one."""

    frames: np.ndarray  # (T,) scene frames
    pose: dict  # property name -> list of flat [f, v, …] arrays, one per vector index
    expressions: list  # one flat [f, v, …] array per expression shape key
    note: str | None = None


def tracking_channels(folder, n_expr: int) -> TrackingChannels:
    """A ``flame_param`` folder as keyframe columns for a head with ``n_expr`` expression keys."""
    tracking = read_tracking(folder)
    frames = tracking.frames
    expr, note = expression_keyframes(tracking, n_expr)
    pose = {prop: keyframe_columns(frames, tracking.params[name]) for name, (prop, _) in POSE_PROPERTIES.items()}
    return TrackingChannels(frames, pose, keyframe_columns(frames, expr), note)


# -- back from Blender: cameras, FLAME parameters, rendered images --------------------------------

AVATAR_PATH_PROPERTY = "mogaface_avatar_path"


def opencv_camera(matrix_world, lens: float, sensor_width: float, sensor_height: float, sensor_fit: str,
                  shift_x: float, shift_y: float, resolution: tuple[int, int],
                  pixel_aspect: tuple[float, float] = (1.0, 1.0), camera_id: str = "blender") -> Camera:
    """A Blender camera (settings as Blender stores them) → an OpenCV :class:`Camera`.

    The inverse of :func:`blender_camera`, for every sensor fit: Blender fits the sensor to
    the width (``HORIZONTAL``, or ``AUTO`` when the frame is at least as wide as tall) or the
    height, and measures shifts in units of that fitted size. ``matrix_world`` may carry scale;
    only its rotation and position are used.
    """
    width, height = int(resolution[0]), int(resolution[1])
    ratio = float(pixel_aspect[1]) / float(pixel_aspect[0])  # pixel height / width = fx / fy
    if sensor_fit == "AUTO":
        horizontal, sensor = width >= height * ratio, sensor_width
    else:
        horizontal = sensor_fit == "HORIZONTAL"
        sensor = sensor_width if horizontal else sensor_height
    fitted = width if horizontal else height * ratio  # the fitted size, in units of a pixel's width
    fx = lens * fitted / sensor
    fy = fx / ratio
    cx = 0.5 * width - shift_x * fitted
    cy = 0.5 * height + shift_y * fitted / ratio
    matrix = np.asarray(matrix_world, np.float64).copy()
    matrix[:3, :3] /= np.linalg.norm(matrix[:3, :3], axis=0)
    c2w_cv = flame_to_blender_matrix(np.eye(4)).T @ matrix @ _CV_TO_BLENDER_CAMERA
    return Camera(K=np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), w2c=np.linalg.inv(c2w_cv),
                  width=width, height=height, camera_id=camera_id)


def head_flame_params(shape, static_offset, expr, pose: dict, n_shape: int, n_expr: int) -> dict:
    """One timestep's FLAME parameters (numpy, unbatched) from a head's identity and rig values.

    ``expr`` and ``pose`` are what a head object shows at a frame (its shape-key values and
    pose properties, i.e. what the keyframes give); counts are fitted to the model rendered.
    """
    params = {"shape": fit_components(shape, n_shape), "expr": fit_components(expr, n_expr)}
    for name, (_, size) in POSE_PROPERTIES.items():
        value = np.asarray(pose.get(name, np.zeros(size)), np.float64).reshape(-1)
        if value.shape != (size,):
            raise InputError(None, name, f"expected {size} values, found {value.shape[0]}")
        params[name] = value
    if static_offset is not None:
        params["static_offset"] = np.asarray(static_offset, np.float64).reshape(-1, 3)
    return params


def rendered_pixels(rgb, alpha) -> np.ndarray:
    """A render's ``rgb (H,W,3)`` and ``alpha (H,W)`` → Blender's flat RGBA float32 (rows flipped)."""
    rgba = np.concatenate([np.asarray(rgb, np.float32), np.asarray(alpha, np.float32)[..., None]], axis=2)
    return image_pixels(rgba)


def render_image_name(camera_name: str, frame: int) -> str:
    """The image datablock a render of ``camera_name`` at ``frame`` goes to."""
    return f"MoGaFace {camera_name} {frame:04d}"


def avatar_location(path) -> tuple[pathlib.Path, tuple[float, float, float]]:
    """A run folder or an avatar file → the avatar file and the background it was trained on.

    Read by :class:`~.run.folder.RunFolder` (``run.json`` checked: a bad background is an error;
    white without one).
    """
    from .run.folder import RunFolder

    run = RunFolder.of_avatar(path)
    return run.avatar_path.resolve(), run.background


_avatar_cache: dict = {}


def load_avatar(path):
    """The avatar of a run folder or avatar file, as :meth:`RunFolder.load_avatar
    <.run.folder.RunFolder.load_avatar>` loads it (with the run's MoGaFace modules when it has
    them), cached while neither the avatar nor the modules file changes."""
    from .run.folder import RunFolder

    run = RunFolder.of_avatar(path)
    path, key = _file_version(run.avatar_path, "avatar")
    if run.has_modules():
        key = key + _file_version(run.modules_path, "MoGaFace modules")[1]
    with _model_cache_lock:
        avatar = _avatar_cache.get(key)
        if avatar is None:
            avatar = run.load_avatar()
            _avatar_cache.clear()
            _avatar_cache[key] = avatar
    return avatar


def render_avatar(avatar, params: dict, camera: Camera, background) -> tuple[np.ndarray, np.ndarray]:
    """``(rgb (H,W,3), alpha (H,W))`` float32: the core's one render of the avatar at ``params``."""
    from .evaluate.protocols import render_frame

    return render_frame(avatar, params, camera, background)
