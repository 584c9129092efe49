"""FLAME and a camera from 2D landmarks: the monocular fit that turns footage into a tracked capture.

Input: per frame, landmarks in pixels with a confidence (0 where a point was not seen), and where
each lies on the head mesh (a :class:`~mogaface.core.flame.landmarks.LandmarkEmbedding`). Output:
the shared shape, and per frame the expression, jaw, gaze (from the iris centres, where the
embedding has them), head rotation and translation; and one pinhole
camera with its focal length (given, or estimated about a phone's).

One fixed camera per clip. The subject turning in front of a still phone and a phone orbiting a
still subject give the same pictures: either is the head's rotation and translation per frame in
front of a fixed camera, which is what ``solve-cameras``, training and Blender's import take.
Several clips of one subject are fitted together: one shape, a camera and a focal length each, and
no smoothness across the cut from one clip to the next.

The fit (torch, every frame at once, L-BFGS; float64 unknowns, the points posed in float32): a
rigid start (the mean head placed at each frame's landmarks, then turned and moved onto them),
then every parameter together on a robust
(Huber) reprojection loss weighted by confidence, Gaussian priors on shape, expression and jaw, and a
smoothness term on second differences over time (a clip's motion is smooth; a detector's noise is
not); then, given the frames' brightness, the photometric stage (:mod:`.photometric`: skin points
whose brightness must agree between frames, or between photos). Only the vertices the landmarks
sit on are posed (:class:`~.head.LandmarkHead`): the same linear blend skinning as
:class:`~mogaface.core.flame.model.FlameModel`, on a few hundred vertices.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from ..camera import Camera, focal_from_35mm
from ..errors import InputError
from ..flame.landmarks import LandmarkEmbedding
from ..flame.model import FlameModel
from .head import LandmarkHead
from .photometric import (
    BrightnessAgreement,
    PhotometricSettings,
    frame_pairs,
    seen_points,
    skin_points,
    vertex_embedding,
)

#: A phone's main camera: about 26 mm in 35 mm terms (its diagonal field of view, 79°).
PHONE_FOCAL_35MM = 26.0
#: Where the fixed camera stands in front of the head (metres along the face's +z), before the fit.
START_DISTANCE = 0.6
#: The heads pose their points (and the skin is sampled) in single precision: the unknowns, the
#: L-BFGS steps and the losses' sums stay double. A third less time, the same fit on the
#: validation clips (docs/tracking.md, *Fitting the head model*).
POSED = torch.float32


@dataclasses.dataclass
class Observations:
    """Landmarks of a clip: ``points (T,L,2)`` pixels, ``confidence (T,L)`` in [0, 1] (0: not seen),
    the frame size, and where the L landmarks lie on the mesh. Photos of several sizes give each
    frame's ``sizes (T,2)``; one lens is fitted to all of them (a focal length in 35 mm terms:
    each frame's in pixels by its diagonal); ``photos``: the frames have no order in time (the
    photometric stage compares every two). Several videos give ``clips (T,)``, which clip each
    frame is from (contiguous, from 0): a lens each, at its first frame's size."""

    points: np.ndarray
    confidence: np.ndarray
    width: int
    height: int
    embedding: LandmarkEmbedding
    sizes: np.ndarray | None = None
    clips: np.ndarray | None = None
    photos: bool = False

    def frame_sizes(self) -> np.ndarray:
        """``(T,2)`` width and height of every frame."""
        if self.sizes is not None:
            return np.asarray(self.sizes, np.float64)
        return np.tile([float(self.width), float(self.height)], (len(self.points), 1))

    def clip_index(self) -> np.ndarray:
        """``(T,)`` each frame's clip (all 0 for one clip or photos)."""
        return np.zeros(len(self.points), np.int64) if self.clips is None else np.asarray(self.clips, np.int64)

    def clip_sizes(self) -> np.ndarray:
        """``(C,2)`` each clip's size (its first frame's)."""
        clip = self.clip_index()
        return self.frame_sizes()[np.searchsorted(clip, np.arange(clip.max() + 1))]

    def check(self, source=None) -> "Observations":
        frames, count = self.confidence.shape
        if self.points.shape != (frames, count, 2):
            raise InputError(source, "points", f"expected ({frames}, {count}, 2), found {self.points.shape}")
        if len(self.embedding.faces) != count:
            raise InputError(source, "embedding", f"{len(self.embedding.faces)} landmarks on the mesh for {count} observed")
        if frames == 0 or not (self.confidence > 0).any():
            raise InputError(source, "landmarks", "no landmark was seen in any frame")
        if not np.isfinite(self.points[self.confidence > 0]).all():
            raise InputError(source, "points", "seen landmarks must be finite")
        clip = self.clip_index()
        if clip.shape != (frames,) or clip[0] != 0 or not np.isin(np.diff(clip), (0, 1)).all():
            raise InputError(source, "clips", f"expected ({frames},) clip numbers counting up from 0, each clip's "
                                              f"frames together")
        return self


@dataclasses.dataclass
class FitSettings:
    steps: int = 200  # L-BFGS iterations of the joint fit (a quarter more for the rigid start)
    focal: float | tuple | None = None  # pixels; None: estimated, starting from a phone's; several clips: one each
    huber_px: float = 2.0  # the robust loss's knee
    # weights beside the reprojection loss (pixels²: half the square of a pixel's error)
    shape_prior: float = 1.0  # of ||shape||² (unit-variance coefficients); chosen on validation clips
    expr_prior: float = 0.02  # of the mean squared expression coefficient
    jaw_prior: float = 5.0  # per radian²; chosen on validation clips (docs/tracking.md)
    focal_prior: float = 4.0  # of log(f / f_phone)²
    smooth: float = 3.0  # of the second differences (per frame²) of pose and expression
    gaze_prior: float = 1.0  # per radian² of the gaze (both eyes turned alike, from the iris centres)
    photometric: PhotometricSettings = dataclasses.field(default_factory=PhotometricSettings)
    seed: int = 0
    shape: np.ndarray | None = None  # held fixed when given (an avatar's identity: a performance drives it)

    def check(self, photos: bool) -> PhotometricSettings:
        """Refuse iterations or a stride no fit can run (before a track spends minutes finding the
        face); returns the photometric stage's settings resolved for photos or a video."""
        photometric = self.photometric.resolved(photos)
        if self.steps < 1 or photometric.steps < 0:
            raise InputError(None, "steps", f"the fit needs at least 1 iteration and the photometric stage 0 (off) or "
                                            f"more; found {self.steps} and {photometric.steps}")
        if photometric.stride < 1:
            raise InputError(None, "stride", f"the photometric stage fits every stride-th frame, stride ≥ 1; found "
                                             f"{photometric.stride}")
        return photometric


@dataclasses.dataclass
class Fit:
    """The fitted parameters (per frame arrays ``(T, n)``, ``shape`` once) and each clip's camera."""

    params: dict[str, np.ndarray]
    cameras: list[Camera]  # each clip's (one for a clip or photos: the first frame's)
    reprojection_px: np.ndarray  # (T,) confidence-weighted RMS per frame
    seen: np.ndarray  # (T,) whether the frame had landmarks
    sizes: np.ndarray | None = None  # (T,2) for frames of several sizes
    clips: np.ndarray | None = None  # (T,) each frame's clip, for several

    @property
    def camera(self) -> Camera:
        """The first clip's camera (every frame's, for one clip)."""
        return self.cameras[0]

    def camera_of(self, t: int, camera_id: str = "cam00") -> Camera:
        """Frame ``t``'s camera: its clip's, or a photo's at its own size with the same lens."""
        return dataclasses.replace(frame_camera(self.cameras, self.clips, self.sizes, t), camera_id=camera_id)

    def frame(self, t: int) -> dict[str, np.ndarray]:
        """Frame ``t``'s parameters in the capture's ``flame_param`` layout (batch of one)."""
        return {name: (value if name == "shape" else value[t])[None].astype(np.float32)
                for name, value in self.params.items()}


def frame_camera(cameras: list[Camera], clips: np.ndarray | None, sizes: np.ndarray | None, t: int) -> Camera:
    """Frame ``t``'s camera of each clip's ``cameras``: its clip's, or (``sizes (T,2)``, photos of
    several sizes) the one lens at the photo's own size (the focal length scaled by the diagonal)."""
    if clips is not None:
        return cameras[int(clips[t])]
    if sizes is None:
        return cameras[0]
    width, height = (int(v) for v in sizes[t])
    focal = cameras[0].fx * math.hypot(width, height) / math.hypot(cameras[0].width, cameras[0].height)
    return start_camera(width, height, focal)


def start_camera(width: int, height: int, focal: float) -> Camera:
    """The clip's fixed camera: in front of the face (FLAME's +z), looking at the origin."""
    return Camera.look_at((0.0, 0.0, START_DISTANCE), (0.0, 0.0, 0.0), width=width, height=height,
                          fx=focal, fy=focal, cx=width / 2, cy=height / 2, camera_id="cam00")


def fit_landmarks(model: FlameModel, observations: Observations, settings: FitSettings = FitSettings(),
                  progress=None, brightness: np.ndarray | None = None) -> Fit:
    """Fit shape, per-frame expression, gaze, jaw and head pose, and the focal length, to a clip's
    landmarks; with the frames' brightness (in [0, 1]: ``(T,H,W)``, or a list of ``(H,W)`` for photos
    of several sizes), then the photometric stage (``settings.photometric``, what it leaves out
    chosen for photos or a video). ``progress(step, steps, rms_px)`` is called now and then."""
    obs = observations.check()
    photometric_settings = settings.check(obs.photos)  # the stage's, for photos or a video
    torch.manual_seed(settings.seed)
    d = torch.float64
    head = LandmarkHead(model, obs.embedding, dtype=POSED)
    frames = obs.points.shape[0]
    points = torch.as_tensor(np.nan_to_num(obs.points), dtype=d)
    weight = torch.as_tensor(obs.confidence, dtype=d).clamp(0, 1)
    seen = (weight > 0).any(1)
    clip = torch.as_tensor(obs.clip_index())
    clip_sizes = obs.clip_sizes()
    phone = torch.tensor([math.log(focal_from_35mm(PHONE_FOCAL_35MM, w, h)) for w, h in clip_sizes], dtype=d)
    given = _clip_focals(settings.focal, len(clip_sizes))
    free = torch.tensor([focal is None for focal in given])
    w2c = torch.as_tensor(start_camera(obs.width, obs.height, 1.0).w2c, dtype=d)  # where it stands: not the lens
    sizes = torch.as_tensor(obs.frame_sizes(), dtype=d)
    centre = sizes[:, None, :] / 2  # (T,1,2)
    lens = (sizes.norm(dim=1) / torch.as_tensor(clip_sizes, dtype=d).norm(dim=1)[clip])[:, None, None]  # photos' sizes
    log_focal = torch.where(free, phone, torch.tensor([math.log(f or 1.0) for f in given], dtype=d))
    log_focal.requires_grad_(bool(free.any()))  # (C,) each clip's; the given ones held (no gradient)

    def frame_focal():
        """``(T,1,1)`` each frame's focal length in pixels."""
        return torch.exp(torch.where(free, log_focal, log_focal.detach()))[clip][:, None, None] * lens

    def cameras() -> list[Camera]:
        focals = torch.exp(log_focal.detach())
        return [start_camera(int(w), int(h), float(f)) for (w, h), f in zip(clip_sizes, focals)]

    # The shared unknowns are stepped in units of 1/sqrt(T): their curvature, a sum over the frames,
    # then matches one frame's own, and L-BFGS converges in far fewer iterations on long clips.
    unit = math.sqrt(frames)
    shape_stepped = _start_shape(settings.shape, model.n_shape, unit)
    # Per frame: the translation in centimetres (a step's scale like the rest), and the gaze as the
    # pitch (about x) and yaw (about y) of both eyes.
    widths = {"expr": model.n_expr, "jaw": 3, "gaze": 2, "rotation": 3, "translation_cm": 3}
    motion = {name: torch.zeros(frames, n, dtype=d, requires_grad=True) for name, n in widths.items()}
    every = torch.arange(frames)

    def project(cam, at):
        """Pixels of points ``cam`` in the camera's frame (:func:`posed`'s) at frames ``at``."""
        d = cam.dtype
        z = cam[..., 2:].clamp_min(1e-3)
        return frame_focal()[at].to(d) * cam[..., :2] / z + centre[at].to(d)

    def reprojection(cam, at):
        residual = (project(cam, at) - points[at]).norm(dim=-1)  # (T,L) pixels
        knee = settings.huber_px
        robust = torch.where(residual < knee, 0.5 * residual ** 2, knee * (residual - 0.5 * knee))
        return (weight[at] * robust).sum() / weight[at].sum().clamp_min(1e-9), residual

    def bending(x, at):
        return _bending(x, at, clip)

    def shared_shape():
        return shape_stepped / unit

    def current() -> dict[str, np.ndarray]:
        with torch.no_grad():
            m = {name: value.numpy().copy() for name, value in motion.items()}
            return {"shape": shared_shape().numpy()[0].copy(), "expr": m["expr"], "rotation": m["rotation"],
                    "neck_pose": np.zeros((frames, 3)), "jaw_pose": m["jaw"],
                    "eyes_pose": eyes_pose(motion["gaze"]).numpy(), "translation": m["translation_cm"] / 100}

    def posed(of, values, view=(w2c[:3, :3], w2c[:3, 3])):
        """The head ``of``'s points in the camera's frame (with ``view=None``: in the world)."""
        return of(shared_shape(), values["expr"], values["rotation"], values["jaw"], values["translation_cm"] / 100,
                  eyes_pose(values["gaze"]), view=view)

    def objective(rigid_only: bool, values: dict, at: torch.Tensor):
        """The loss at frames ``at``, whose per-frame unknowns are ``values``."""
        loss, residual = reprojection(posed(head, values), at)
        smooth = bending(values["rotation"], at) + bending(values["translation_cm"] / 100, at)
        if rigid_only:
            return loss + settings.smooth * scale * smooth, residual
        prior = (settings.shape_prior * shared_shape().pow(2).sum() * scale + settings.gaze_prior * values["gaze"].pow(2).mean()
                 + settings.expr_prior * values["expr"].pow(2).mean() + settings.jaw_prior * values["jaw"].pow(2).mean())
        prior = prior + settings.focal_prior * ((log_focal - phone) ** 2 * free).sum()
        smooth = smooth + 0.01 * bending(values["expr"], at) + bending(values["jaw"], at) + bending(values["gaze"], at)
        return loss + prior + settings.smooth * scale * smooth, residual

    def photometric(agreement, skin):
        def stage_objective(rigid_only, values, at):
            loss, residual = objective(rigid_only, values, at)
            return loss + photometric_settings.weight * agreement(project(posed(skin, values), at)), residual
        return stage_objective

    # 1. Rigid start: the mean head placed where each frame's landmarks are, at the depth their
    # spread gives, then turned and moved onto them; 2. everything; 3. (with the frames' brightness)
    # everything but the focal length, the skin's brightness agreeing between frames: first on a
    # video's every ``stride``-th frame (:func:`_knots`; the frames between moved as their knots
    # were: the clip-long turn, cheaply), then on every frame (each one's own correction).
    scale = 1.0 / frames
    with torch.no_grad():
        motion["translation_cm"].copy_(100 * _placed(posed(head, motion, view=None), points, weight, frame_focal()[:, 0, 0],
                                                     centre[:, 0], w2c))
    shared = [shape_stepped] * shape_stepped.requires_grad
    # (the unknowns, rigid only, the photometric stage's stride (None: the landmarks alone), iterations)
    stages = [([motion["rotation"], motion["translation_cm"]], True, None, max(settings.steps // 4, 1)),
              (shared + list(motion.values()) + [log_focal] * log_focal.requires_grad, False, None, settings.steps)]
    if brightness is not None and len(frame_pairs(obs.clip_index(), photometric_settings.gaps, obs.photos)):
        stages += [(None, False, photometric_settings.stride, photometric_settings.steps),
                   (None, False, 1, photometric_settings.fine_steps())]  # then every frame, after a stride
    stages = [stage for stage in stages if stage[3] > 0]
    done, total = 0, sum(stage[3] for stage in stages)
    for unknowns, rigid_only, stride, steps in stages:
        values, at, stage_objective = motion, every, objective
        if stride is not None:  # the photometric stage: what each frame sees, from the fit so far
            knot_frames = _knots(obs.clip_index(), stride)
            knots = torch.as_tensor(knot_frames)
            gaps = tuple(sorted({max(1, round(gap / stride)) for gap in photometric_settings.gaps}))
            pairs = frame_pairs(obs.clip_index()[knot_frames], gaps, obs.photos)
            clip_cameras = cameras()
            frame_cameras = [frame_camera(clip_cameras, obs.clips, obs.sizes, int(t)) for t in knots]
            at_knots = {name: value[knots].detach().clone().requires_grad_() for name, value in motion.items()}
            values, at = at_knots, knots
            unknowns = shared + list(at_knots.values())
            term = _photometric_term(model, _at(current(), knot_frames), frame_cameras, pairs,
                                     _at(brightness, knot_frames), seen.numpy()[knot_frames], photometric_settings)
            stage_objective = photometric(*term)
        optimiser = torch.optim.LBFGS(unknowns, lr=1.0, max_iter=steps, history_size=30,
                                      line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-12)

        def closure():
            optimiser.zero_grad()
            loss, residual = stage_objective(rigid_only, values, at)
            loss.backward()
            return loss

        optimiser.step(closure)
        with torch.no_grad():
            for name, value in values.items() if stride is not None else ():
                _spread(motion[name], value, knots)
        done += steps
        if progress is not None:
            with torch.no_grad():
                _, residual = objective(rigid_only, motion, every)
            progress(done, total, float(_rms(residual, weight).mean()))

    with torch.no_grad():
        _, residual = reprojection(posed(head, motion), every)
    return Fit(current(), cameras(), _rms(residual, weight).numpy(), seen.numpy(), obs.sizes, obs.clips)


def _knots(clips: np.ndarray, stride: int) -> np.ndarray:
    """The frames the photometric stage fits: every ``stride``-th of each clip (``clips (T,)``,
    each frame's), and its last."""
    frames = np.arange(len(clips))
    first, last = np.searchsorted(clips, clips, "left"), np.searchsorted(clips, clips, "right") - 1
    return frames[((frames - first) % stride == 0) | (frames == last)]


def _bending(x: torch.Tensor, at: torch.Tensor, clips: torch.Tensor) -> torch.Tensor:
    """The sum of squared second differences (per frame²) within each clip (``clips (T,)``, each
    frame's) of the piecewise linear path through ``x (K,n)`` at frames ``at (K,)``: at every
    frame, the frames' own."""
    if len(x) < 3:
        return x.sum() * 0
    slope = (x[1:] - x[:-1]) / (at[1:] - at[:-1]).to(x.dtype)[:, None]
    same_clip = (clips[at][2:] == clips[at][:-2]).to(x.dtype)[:, None]  # clips are contiguous
    return ((slope[1:] - slope[:-1]).pow(2) * same_clip).sum()


def _spread(full: torch.Tensor, fitted: torch.Tensor, knots: torch.Tensor) -> None:
    """Move every frame of ``full (T,n)`` as the two knots around it moved (to ``fitted``, at
    ``knots``), in proportion to how near each is: the knots of one clip hold its first and last
    frames, so no frame follows a knot of another clip."""
    change = fitted - full[knots]
    frame = torch.arange(len(full))
    left = (torch.searchsorted(knots, frame, right=True) - 1).clamp(0, len(knots) - 2)
    toward = ((frame - knots[left]).to(full.dtype) / (knots[left + 1] - knots[left]).to(full.dtype)).clamp(0, 1)[:, None]
    full += (1 - toward) * change[left] + toward * change[left + 1]


def _at(values, frames: np.ndarray):
    """``values`` at ``frames``: per-frame arrays (a dict's, beside its ``shape``) or a list."""
    if isinstance(values, dict):
        return {name: value if name == "shape" else value[frames] for name, value in values.items()}
    return [values[t] for t in frames] if isinstance(values, list) else values[frames]


def _clip_focals(focal, clips: int) -> list:
    """The given focal length(s) as one per clip (None: estimated)."""
    focals = list(focal) if isinstance(focal, list | tuple) else [focal] * clips
    if len(focals) != clips:
        raise InputError(None, "focal", f"expected one focal length per clip ({clips}), found {len(focals)}")
    return focals


def _photometric_term(model: FlameModel, params: dict, cameras: list[Camera], pairs: np.ndarray, brightness,
                      frames: np.ndarray, settings: PhotometricSettings) -> tuple[BrightnessAgreement, LandmarkHead]:
    """The photometric stage's loss and the head posed at its skin points (:mod:`.photometric`);
    ``cameras``: each frame's; ``pairs (N,2)``: the frames compared; ``frames (T,)``: those with
    landmarks (the others' parameters are a guess)."""
    points = skin_points(model, settings.points, settings.seed)
    seen, normals = seen_points(model, params, cameras, points)
    skin = LandmarkHead(model, vertex_embedding(model.faces.numpy(), points), dtype=POSED)
    return BrightnessAgreement(brightness, seen & frames[:, None], settings, pairs, normals), skin


def eyes_pose(gaze: torch.Tensor) -> torch.Tensor:
    """FLAME's ``eyes_pose (T,6)`` of a gaze ``(T,2)``: both eyes turned alike by the axis-angle
    ``(pitch, yaw, 0)`` (at a phone's distance the eyes converge too little to tell them apart)."""
    turn = torch.cat([gaze, torch.zeros_like(gaze[:, :1])], dim=1)
    return torch.cat([turn, turn], dim=1)


def _start_shape(fixed, count: int, unit: float) -> torch.Tensor:
    """``(1, count)`` times ``unit``: zeros to fit, or the given identity held fixed (cut or padded
    to ``count``)."""
    if fixed is None:
        return torch.zeros(1, count, dtype=torch.float64, requires_grad=True)
    values = np.asarray(fixed, np.float64).reshape(-1)[:count]
    return unit * torch.as_tensor(np.pad(values, (0, count - len(values))), dtype=torch.float64)[None]


def _placed(rest: torch.Tensor, points: torch.Tensor, weight: torch.Tensor, focal: torch.Tensor, centre: torch.Tensor,
            w2c: torch.Tensor) -> torch.Tensor:
    """Per frame, the translation that puts the unposed head's landmarks ``rest (T,L,3)`` where the
    observed ones are (their weighted centroid) at the depth their spread gives (pinhole similar
    triangles); frames without landmarks get the mean of the others."""
    total = weight.sum(1, keepdim=True).clamp_min(1e-9)
    centroid_2d = (weight[..., None] * points).sum(1) / total  # (T,2)
    spread_2d = torch.sqrt((weight * ((points - centroid_2d[:, None]) ** 2).sum(-1)).sum(1) / total[:, 0])
    centroid_3d = rest.mean(1)  # (T,3)
    spread_3d = torch.sqrt(((rest - centroid_3d[:, None])[..., :2] ** 2).sum(-1).mean(1))  # facing the camera
    depth = focal * spread_3d / spread_2d.clamp_min(1e-6)  # focal, centre: (T,), (T,2)
    in_camera = torch.cat([(centroid_2d - centre) * (depth / focal)[:, None], depth[:, None]], 1)
    world = (in_camera - w2c[:3, 3]) @ w2c[:3, :3]  # the camera's frame to the world (w2c is rigid)
    seen = weight.sum(1) > 0
    world[~seen] = world[seen].mean(0)
    return world - centroid_3d


def _rms(residual: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Confidence-weighted RMS per frame (0 for a frame without landmarks)."""
    with torch.no_grad():
        total = weight.sum(1)
        return torch.sqrt((weight * residual ** 2).sum(1) / total.clamp_min(1e-9)) * (total > 0)
