"""Training the refiner on a finished run, the avatar frozen; no gradient descent, three measured
passes over the run:

1. **Known offsets.** For a training timestep, the run's parameters are jittered (the start) and
   rendered in every camera's head window; then the avatar is rendered at the start plus a new
   random offset (:class:`.sampler.OffsetSampler`) in the same windows. Per camera, a ridge
   regression of the pooled differences on the offsets gives the forward model ``A`` and what it
   leaves unexplained (its residual variance). The offsets are new every time, so nothing can be
   memorised.
2. **The capture gap.** At the run's own parameters (fine-tuned when the run fine-tuned them: the
   teacher), the captured training views are compared with the avatar's renders; per camera, the
   mean of that gap, its leading components and the variance they leave tell the solve what in a
   capture is not a parameter change.
3. **The full-size curvature.** At a few training timesteps' parameters, each camera's crop is
   rendered at full size with every regressed value moved alone (finite differences); the mean
   ``JᵀJ`` per pixel is the matrix of the pass's closing Gauss–Newton step (:mod:`.model`).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import numpy as np
import torch

from ..data.capture_info import capture_info
from ..data.target import target_image
from ..errors import InputError
from ..run.cameras import InputCameras
from ..run.folder import MOTION_KEYS, RunFolder
from .files import REFINER_FILE, save_refiner
from .groups import add_offset, scale_vector
from .model import LinearRefiner
from .sampler import OffsetSampler
from .views import crop_cameras, image_crop, pooled_difference, posed, render_crop

# The inference settings (prior, gap_rank, full_size_steps, damping) as chosen on validation frames by
# ``bench refiner_search`` (docs/notebook/2026-11-27-validation-and-unseen-subjects.md).
DEFAULT_SPEC = {"grid": 16, "render_limit": 512, "prior": 32.0, "gap_rank": 4, "full_size_steps": 3, "damping": 3e-5}
_DIFFERENCE_STEP = 0.3  # finite-difference step of the curvature, in multiples of each group's expected error
_CAMERAS_AT_ONCE = 4  # crops held per posing while measuring the curvature (memory: a crop per regressed value)


@dataclasses.dataclass
class RefinerSettings:
    starts: int = 100  # jittered training frames rendered in every camera's window
    offsets_per_start: int = 4  # observations per start (so ``starts × offsets_per_start`` samples per camera)
    gap_timesteps: int = 40  # training timesteps whose captures measure the gap
    curvature_timesteps: int = 4  # training timesteps at which the full-size curvature is measured
    seed: int = 0
    threads: int = 2
    offset_width: float = 1.0  # offsets in multiples of each group's expected error (:mod:`.sampler`)
    offset_groups: tuple[str, ...] | None = None  # None: every group of :mod:`.groups`
    ridge: float = 1e-3
    spec: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_SPEC))  # a partial one: defaults for the rest

    def check(self) -> None:
        for name in ("starts", "offsets_per_start", "threads"):
            if getattr(self, name) < 1:
                raise InputError(None, name, f"must be at least 1, got {getattr(self, name)}")
        for name in ("gap_timesteps", "curvature_timesteps"):
            if getattr(self, name) < 0:
                raise InputError(None, name, f"must be at least 0, got {getattr(self, name)}")


def frozen_avatar(run_dir):
    avatar = RunFolder(run_dir).load_avatar()
    for module in (avatar, getattr(avatar, "avatar", None), getattr(avatar, "model", None)):
        if isinstance(module, torch.nn.Module):
            module.requires_grad_(False)
    return avatar


class _Run:
    """The run's training timesteps with their parameters, and the capture's cameras (the run's
    refined poses where training refined them) and frames."""

    def __init__(self, run: RunFolder, capture):
        self.background = run.background
        self.cameras = InputCameras.of_run(capture, run.root)
        self.timesteps = [t for t in run.trained_timesteps if t in capture.timestep_ids]
        if not self.timesteps:
            raise InputError(run.flame_param_dir, None, "the run holds no FLAME parameters (is training finished?)")
        tracked = {t: capture.flame_params(t) for t in self.timesteps}
        self.params = {t: {**tracked[t], **{k: v for k, v in run.flame_params(t).items() if k in MOTION_KEYS}}
                       for t in self.timesteps}
        self.camera_ids = sorted(capture.cameras)
        self.training_frames: dict[int, list] = {}
        for frame in capture.frames("train"):
            if frame.timestep_index in self.params:
                self.training_frames.setdefault(frame.timestep_index, []).append(frame)


def _forward_models(avatar, capture, run: _Run, settings, spec, rng, emit, should_stop):
    n_expr = spec["n_expr"]
    scales = scale_vector(n_expr).numpy()
    sampler = OffsetSampler(n_expr, width=settings.offset_width, seed=settings.seed, groups=settings.offset_groups)
    background = run.background
    features = {c: [] for c in run.camera_ids}
    offsets = []
    for index in range(settings.starts):
        if should_stop():
            break
        t = int(rng.choice(run.timesteps))
        start = add_offset(run.params[t], (rng.normal(size=len(scales)) * 0.5 * scales).astype(np.float32), n_expr)
        cameras = [run.cameras.at(c, t) for c in run.camera_ids]
        head = posed(avatar, start)
        crops = crop_cameras(cameras, head.vertices, spec["render_limit"])
        base = [render_crop(head, crop, background) for crop in crops]
        for _ in range(settings.offsets_per_start):
            offset = sampler()
            moved = posed(avatar, add_offset(start, offset, n_expr))
            for camera_id, crop, rendered in zip(run.camera_ids, crops, base):
                observed = render_crop(moved, crop, background)
                features[camera_id].append(pooled_difference(observed, rendered, spec["grid"]).double())
            offsets.append(offset / scales)
        emit("iter", step=index + 1, steps=settings.starts, stage="offsets")
    if len(offsets) < 2:
        raise InputError(None, "starts", "stopped before the refiner saw enough rendered offsets")
    x = torch.as_tensor(np.stack(offsets), dtype=torch.float64)
    ridge = settings.ridge * len(offsets) * torch.eye(x.shape[1], dtype=torch.float64)
    forward, residual, explained = [], [], []
    for camera_id in run.camera_ids:
        f = torch.stack(features[camera_id])
        a = torch.linalg.solve(x.T @ x + ridge, x.T @ f).T  # (D, P)
        forward.append(a)
        residual.append((f - x @ a.T).var(0) + 1e-6)
        explained.append(float(1.0 - residual[-1].sum() / f.var(0).sum().clamp_min(1e-12)))
    return torch.stack(forward), torch.stack(residual), len(offsets), float(np.mean(explained))


def _capture_gap(avatar, capture, run: _Run, settings, spec, rng, emit):
    """Per camera, the mean of (capture − render) at the run's parameters, its ``gap_rank`` leading
    components (scaled to their standard deviation) and the variance they leave; cameras with no
    training view (e.g. a held-out one) get zero mean, no components and the average variance."""
    background = run.background
    recorded = capture_info(capture.root).get("background")
    chosen = rng.permutation(run.timesteps)[:settings.gap_timesteps]
    gaps: dict[str, list] = {}
    for index, t in enumerate(chosen):
        frames = run.training_frames.get(int(t), [])
        cameras = [run.cameras(f) for f in frames]
        head = posed(avatar, run.params[int(t)])
        for frame, crop in zip(frames, crop_cameras(cameras, head.vertices, spec["render_limit"])):
            observed = image_crop(target_image(capture, frame, background, recorded), crop, background)
            rendered = render_crop(head, crop, background)
            gaps.setdefault(frame.camera_id, []).append(pooled_difference(observed, rendered, spec["grid"]).double())
        emit("iter", step=index + 1, steps=len(chosen), stage="gap")
    size, rank = 3 * spec["grid"] ** 2, spec["gap_rank"]
    measured = {c: torch.stack(g) for c, g in gaps.items() if len(g) >= 2}
    average = (torch.stack([g.var(0) for g in measured.values()]).mean(0) if measured
               else torch.zeros(size, dtype=torch.float64))
    means, variances, bases = [], [], []
    for camera_id in run.camera_ids:
        basis = torch.zeros(rank, size, dtype=torch.float64)
        if camera_id not in measured:
            means.append(torch.zeros(size, dtype=torch.float64))
            variances.append(average)
            bases.append(basis)
            continue
        gap = measured[camera_id]
        centred = gap - gap.mean(0)
        _, values, vectors = torch.linalg.svd(centred, full_matrices=False)
        kept = min(rank, len(values))
        basis[:kept] = vectors[:kept] * (values[:kept, None] / (len(gap) - 1) ** 0.5)
        means.append(gap.mean(0))
        variances.append((gap.var(0) - (basis ** 2).sum(0)).clamp_min(0.0))
        bases.append(basis)
    return torch.stack(means), torch.stack(variances), torch.stack(bases), sorted(measured)


def _curvatures(avatar, run: _Run, settings, spec, rng, emit, should_stop):
    """Per camera, the mean over ``curvature_timesteps`` of ``JᵀJ / pixels`` of its full-size crop
    (J by forward differences, in multiples of each group's expected error); zero with none (the
    pass then takes no full-size step)."""
    n_expr = spec["n_expr"]
    scales = scale_vector(n_expr).numpy()
    size = len(scales)
    total = {c: torch.zeros(size, size, dtype=torch.float64) for c in run.camera_ids}
    chosen = rng.permutation(run.timesteps)[:settings.curvature_timesteps if spec["full_size_steps"] else 0]
    done = 0
    for index, t in enumerate(chosen):
        if should_stop():
            break
        params = run.params[int(t)]
        moved = [add_offset(params, (np.eye(size)[j] * _DIFFERENCE_STEP * scales).astype(np.float32), n_expr)
                 for j in range(size)]
        head = posed(avatar, params)
        for first in range(0, len(run.camera_ids), _CAMERAS_AT_ONCE):
            ids = run.camera_ids[first:first + _CAMERAS_AT_ONCE]
            crops = crop_cameras([run.cameras.at(c, int(t)) for c in ids], head.vertices, spec["render_limit"])
            base = [render_crop(head, crop, run.background).flatten() for crop in crops]
            columns = [[] for _ in ids]
            for shifted in moved:
                moved_head = posed(avatar, shifted)
                for column, crop, rendered in zip(columns, crops, base):
                    column.append((render_crop(moved_head, crop, run.background).flatten() - rendered)
                                  / _DIFFERENCE_STEP)
            for camera_id, column, crop in zip(ids, columns, crops):
                jacobian = torch.stack(column, 1).double()
                total[camera_id] += jacobian.T @ jacobian / (crop[1].width * crop[1].height)
        done += 1
        emit("iter", step=index + 1, steps=len(chosen), stage="curvature")
    return torch.stack([total[c] / max(1, done) for c in run.camera_ids])


def train_refiner(run_dir, settings: RefinerSettings | None = None, out: str | pathlib.Path | None = None,
                  listeners=(), should_stop=lambda: False) -> dict:
    """Train a refiner for ``run_dir``'s avatar; write it to ``out`` (default ``RUN/refiner.pt``)."""
    settings = settings or RefinerSettings()
    settings.check()
    torch.set_num_threads(settings.threads)
    rng = np.random.default_rng(settings.seed)
    folder = RunFolder(run_dir)
    capture = folder.open_capture()
    avatar = frozen_avatar(folder.root)
    run = _Run(folder, capture)
    spec = {**DEFAULT_SPEC, **settings.spec, "n_expr": avatar.flame.n_expr}

    def emit(event: str, **fields):
        for listener in listeners:
            listener({"event": event, **fields})

    emit("start", step=0, steps=settings.starts, timesteps=len(run.timesteps), cameras=len(run.camera_ids))
    began = time.perf_counter()
    forward, residual, samples, explained = _forward_models(avatar, capture, run, settings, spec, rng, emit,
                                                            should_stop)
    if should_stop():  # stopped: keep the offsets learnt so far, measure no gap and no curvature
        settings = dataclasses.replace(settings, gap_timesteps=0, curvature_timesteps=0)
    gap_mean, gap_var, gap_basis, gap_cameras = _capture_gap(avatar, capture, run, settings, spec, rng, emit)
    curvature = _curvatures(avatar, run, settings, spec, rng, emit, should_stop)
    refiner = LinearRefiner(spec, run.camera_ids, forward, residual, gap_mean, gap_var, gap_basis, curvature)
    trained = {"samples_per_camera": samples, "seed": settings.seed, "gap_cameras": gap_cameras,
               "seconds": time.perf_counter() - began, "explained": explained}
    path = pathlib.Path(out) if out is not None else folder.root / REFINER_FILE
    save_refiner(refiner, path, trained)
    emit("done", path=str(path), **{k: v for k, v in trained.items() if k != "gap_cameras"})
    return {"path": str(path), **trained}
