"""Training the refiner on a finished run, the avatar frozen.

Each step takes a training frame's parameters (as the run left them), jitters them (the start),
draws a new offset (:class:`.sampler.OffsetSampler`), renders the avatar at start + offset from a
few training views as the observation, renders the start in the same head windows, and regresses
the offset. The offset is new every step, so no frame can be memorised.

When the run fine-tuned its per-timestep parameters, a share of steps instead distils that
fine-tuning on the captured views: start at the tracked parameters, observe the captured images,
regress fine-tuned − tracked. The fine-tuning is the teacher that closes the gap between the
avatar's renders and real captures.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import time

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import InputError
from ..evaluate.images import target_image
from ..evaluate.run_folder import MOTION_KEYS, RunFolder, capture_info
from ..mogaface.avatar import load_run_avatar
from .files import REFINER_FILE, save_refiner
from .groups import add_offset, flatten, scale_vector
from .network import Refiner
from .sampler import OffsetSampler
from .views import camera_tokens, crop_cameras, image_crops, posed, render_crops

DEFAULT_SPEC = {"crop": 96, "width": 24, "feature_dim": 128, "heads": 4, "layers": 1}


@dataclasses.dataclass
class RefinerSettings:
    steps: int = 800
    views: int = 3  # training views per sample
    offsets_per_start: int = 2  # observations per rendered start (the start's renders are shared)
    lr: float = 2e-3
    seed: int = 0
    threads: int = 2
    distill: bool | None = None  # None: when the run fine-tuned its parameters
    distill_share: float = 0.3
    image_noise: float = 0.005  # on rendered observations, so renders are not the only thing it can read
    offset_width: float = 2.0  # offsets in multiples of each group's expected error (:mod:`.sampler`)
    offset_groups: tuple[str, ...] | None = None  # None: every group of :mod:`.groups`
    spec: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_SPEC))

    def check(self) -> None:
        for name in ("steps", "views", "offsets_per_start", "threads"):
            if getattr(self, name) < 1:
                raise InputError(None, name, f"must be at least 1, got {getattr(self, name)}")
        if not 0.0 <= self.distill_share <= 1.0:
            raise InputError(None, "distill_share", f"expected a share in [0, 1], got {self.distill_share}")


def frozen_avatar(run_dir):
    avatar = load_run_avatar(run_dir)
    modules = [avatar, getattr(avatar, "avatar", None), getattr(avatar, "model", None)]
    for module in modules:
        if isinstance(module, torch.nn.Module):
            module.requires_grad_(False)
    return avatar


class _Frames:
    """The run's training timesteps: its parameters, the tracked ones, training cameras per timestep."""

    def __init__(self, run: RunFolder, capture, n_expr: int):
        if not run.trained_timesteps:
            raise InputError(run.flame_param_dir, None, "the run holds no FLAME parameters (is training finished?)")
        self.timesteps = run.trained_timesteps
        self.params = {t: run.flame_params(t) for t in self.timesteps}
        self.frames: dict[int, list] = {}
        for frame in capture.frames("train"):
            if frame.timestep_index in self.params:
                self.frames.setdefault(frame.timestep_index, []).append(frame)
        self.timesteps = [t for t in self.timesteps if self.frames.get(t)]
        self.tracked = {t: {**self.params[t], **{k: v for k, v in capture.flame_params(t).items() if k in MOTION_KEYS}}
                        for t in self.timesteps}
        self.teaching = {t: flatten(self.params[t], n_expr) - flatten(self.tracked[t], n_expr) for t in self.timesteps}
        self.fine_tuned = max(float(np.abs(v).max()) for v in self.teaching.values()) > 1e-6
        self.expr_spread = np.maximum(np.std([self.params[t]["expr"][:n_expr] for t in self.timesteps], axis=0), 0.1)


def train_refiner(run_dir, settings: RefinerSettings | None = None, out: str | pathlib.Path | None = None,
                  listeners=(), should_stop=lambda: False) -> dict:
    """Train a refiner for ``run_dir``'s avatar; write it to ``out`` (default ``RUN/refiner.pt``)."""
    settings = settings or RefinerSettings()
    settings.check()
    torch.set_num_threads(settings.threads)
    torch.manual_seed(settings.seed)
    rng = np.random.default_rng(settings.seed)
    run = RunFolder(run_dir)
    capture = run.open_capture()
    avatar = frozen_avatar(run.root)
    n_expr = avatar.flame.n_expr
    frames = _Frames(run, capture, n_expr)
    distill = frames.fine_tuned if settings.distill is None else settings.distill
    if distill and not frames.fine_tuned:
        raise InputError(run.flame_param_dir, None, "distillation needs a run that fine-tuned its parameters")
    refiner = Refiner({**settings.spec, "n_expr": n_expr})
    scales = scale_vector(n_expr)
    sampler = OffsetSampler(n_expr, frames.expr_spread, width=settings.offset_width, seed=settings.seed,
                            groups=settings.offset_groups)
    optimiser = torch.optim.Adam(refiner.parameters(), lr=settings.lr)
    background = run.background
    recorded = capture_info(capture.root).get("background")

    def emit(event: str, **fields):
        for listener in listeners:
            listener({"event": event, **fields})

    def synthetic():
        t = int(rng.choice(frames.timesteps))
        picks = rng.choice(len(frames.frames[t]), min(settings.views, len(frames.frames[t])), replace=False)
        cameras = [capture.camera(frames.frames[t][i]) for i in picks]
        start = add_offset(frames.params[t], (rng.normal(size=len(scales)) * 0.5 * scales.numpy()).astype(np.float32),
                           n_expr)
        vertices = posed(avatar, start)
        crops = crop_cameras(cameras, vertices, refiner.crop)
        rendered = render_crops(avatar, vertices, crops, background)
        tokens = camera_tokens(cameras, start)
        samples = []
        for _ in range(settings.offsets_per_start):
            offset = sampler(flatten(start, n_expr))
            observed = render_crops(avatar, posed(avatar, add_offset(start, offset, n_expr)), crops, background)
            noise = settings.image_noise * torch.as_tensor(rng.normal(size=observed.shape), dtype=torch.float32)
            samples.append(((observed + noise).clamp(0, 1), rendered, tokens, torch.as_tensor(offset)))
        return samples

    def distilled():
        t = int(rng.choice(frames.timesteps))
        picks = rng.choice(len(frames.frames[t]), min(settings.views, len(frames.frames[t])), replace=False)
        chosen = [frames.frames[t][i] for i in picks]
        cameras = [capture.camera(f) for f in chosen]
        start = frames.tracked[t]
        vertices = posed(avatar, start)
        crops = crop_cameras(cameras, vertices, refiner.crop)
        images = [target_image(capture, f, background, recorded) for f in chosen]
        observed = image_crops(images, cameras, vertices, refiner.crop, background)
        return [(observed, render_crops(avatar, vertices, crops, background), camera_tokens(cameras, start),
                 torch.as_tensor(frames.teaching[t]))]

    emit("start", step=0, steps=settings.steps, distill=bool(distill), timesteps=len(frames.timesteps))
    began = time.perf_counter()
    step = 0
    losses = []
    for step in range(1, settings.steps + 1):
        if should_stop():
            step -= 1
            emit("stopped", step=step)
            break
        for group in optimiser.param_groups:
            group["lr"] = settings.lr * 0.5 * (1.0 + math.cos(math.pi * (step - 1) / settings.steps))
        samples = distilled() if distill and rng.uniform() < settings.distill_share else synthetic()
        observed, rendered, tokens, target = (torch.stack(x) for x in zip(*samples))
        predicted = refiner(observed, rendered, tokens)
        loss = F.smooth_l1_loss(predicted / scales, (target / scales)[:, None].expand_as(predicted))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
        if step % 10 == 0 or step == settings.steps:
            emit("iter", step=step, steps=settings.steps, loss=float(np.mean(losses[-10:])),
                 seconds=time.perf_counter() - began)
    trained = {"steps": step, "seed": settings.seed, "distilled": bool(distill), "views": settings.views,
               "seconds": time.perf_counter() - began, "final_loss": float(np.mean(losses[-50:])) if losses else None}
    path = pathlib.Path(out) if out is not None else run.root / REFINER_FILE
    save_refiner(refiner, path, trained)
    emit("done", step=step, path=str(path), **{k: v for k, v in trained.items() if k != "steps"})
    return {"path": str(path), **trained}
