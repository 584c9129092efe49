"""Where one training step's time goes: a stage-by-stage profile of Freeze and the full method.

Same scene as ``bench train`` (10 views, 256², default head, every Gaussian tripled: about 38k),
densification off; ``--scale real``: the scene of ``bench train --scale real`` (802×550, 16
training cameras, about 100k Gaussians), where a user's capture spends its time. The trainer runs unchanged; the functions that make up a step are wrapped
with a stopwatch that counts each stage's exclusive time (a stage called inside another is
subtracted from it), so the stages plus "other" add up to the whole step. "other" is what no
wrapper covers: Python and torch dispatch between the stages, the frame sampler, the learning
rate update, the bank's pre-step reads. Reports milliseconds per step for each stage, and the
changed parts of the step timed against the paths they replaced (``changes_old_vs_new``, ratios in
the same run), with the load average.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import tempfile
import time

from .timing import median_ms


class Stopwatch:
    """Exclusive time per label over nested, wrapped calls (one thread)."""

    def __init__(self):
        self.totals: dict[str, float] = {}
        self._stack: list[list] = []

    @contextlib.contextmanager
    def stage(self, label: str):
        self._stack.append([label, time.perf_counter(), 0.0])
        try:
            yield
        finally:
            name, start, children = self._stack.pop()
            elapsed = time.perf_counter() - start
            self.totals[name] = self.totals.get(name, 0.0) + elapsed - children
            if self._stack:
                self._stack[-1][2] += elapsed

    def wrap(self, owner, attribute: str, label: str, static: bool = False):
        original = getattr(owner, attribute)
        watch = self

        def wrapped(*args, **kwargs):
            with watch.stage(label):
                return original(*args, **kwargs)

        setattr(owner, attribute, staticmethod(wrapped) if static else wrapped)
        return lambda: setattr(owner, attribute, staticmethod(original) if static else original)


def _instrument(watch: Stopwatch) -> list:
    import torch

    from mogaface.core.avatar import avatar as avatar_module
    from mogaface.core.avatar.densify import DensifyStrategy
    from mogaface.core.avatar.gaussians import BoundGaussians
    from mogaface.core.correction.model import MoGaFace
    from mogaface.core.correction.training import CorrectionTraining
    from mogaface.core.splat import api
    from mogaface.core.splat.function import Project, Rasterize
    from mogaface.core.train import correction_part, data, losses, training_view

    undo = [
        watch.wrap(data.TrainingData, "target", "image loading"),
        watch.wrap(avatar_module.Avatar, "posed_vertices", "FLAME"),
        watch.wrap(BoundGaussians, "world", "binding"),
        watch.wrap(correction_part, "world_with_offsets", "binding"),
        watch.wrap(CorrectionTraining, "step", "MoGaFace correction (encoder, fusion, head, bank)"),
        watch.wrap(MoGaFace, "texture_offsets", "MoGaFace texture attention"),
        watch.wrap(api, "sh_to_rgb", "render: SH colours"),
        watch.wrap(Project, "forward", "render: projection forward", static=True),
        watch.wrap(Rasterize, "forward", "render: rasterise forward", static=True),
        watch.wrap(Project, "backward", "render: projection backward", static=True),
        watch.wrap(Rasterize, "backward", "render: rasterise backward", static=True),
        watch.wrap(losses, "ssim", "loss: SSIM"),
        watch.wrap(training_view, "image_loss", "loss: L1 and the rest"),
        watch.wrap(training_view, "position_hinge", "loss: hinges"),
        watch.wrap(training_view, "scaling_hinge", "loss: hinges"),
        watch.wrap(torch.Tensor, "backward", "backward: everything but the render"),
        watch.wrap(torch.optim.Adam, "step", "optimiser (Adam)"),
        watch.wrap(DensifyStrategy, "observe", "densification statistics"),
        watch.wrap(CorrectionTraining, "record", "MoGaFace commit (bank, running means)"),
        watch.wrap(CorrectionTraining, "commit", "MoGaFace commit (bank, running means)"),
        watch.wrap(training_view, "psnr", "progress values"),
    ]
    return undo


def profile(trainer, steps: int) -> dict:
    """Per-stage milliseconds per step of ``steps`` training steps (after the caller's warm-up)."""
    watch = Stopwatch()
    undo = _instrument(watch)
    try:
        times = []
        for _ in range(steps):
            start = time.perf_counter()
            with watch.stage("other (Python, dispatch, sampler)"):
                trainer.train_step()
            times.append(time.perf_counter() - start)
    finally:
        for restore in reversed(undo):
            restore()
    total = sum(times)
    stages = {k: round(1000 * v / steps, 2) for k, v in sorted(watch.totals.items(), key=lambda kv: -kv[1])}
    render = sum(v for k, v in watch.totals.items() if k.startswith("render:"))
    return {"step_ms": round(1000 * total / steps, 2), "median_step_ms": round(1000 * statistics.median(times), 2),
            "render_share": round(render / total, 3), "stages_ms": stages}


def path_ratios(trainer, repeats: int) -> dict:
    """The step's changed parts against the paths they replaced, timed here on this avatar's tensors.

    ``old_ms / new_ms`` per change: Adam's per-tensor loop against the fused kernel; the binding
    hinges of the visible Gaussians by gathering rows against a masked mean (forward + backward);
    the densification statistics by gathered rows against whole-array updates.
    """
    import torch

    from mogaface.core.avatar.densify import DensifyStrategy
    from mogaface.core.train import losses

    g = trainer.avatar.gaussians
    n = len(g)
    generator = torch.Generator().manual_seed(0)
    out = {}

    def adam(**kind):
        params = [torch.nn.Parameter(t.detach().clone()) for t in g.parameters()]
        for p in params:
            p.grad = torch.randn(p.shape, generator=generator)
        optimizer = torch.optim.Adam([{"params": [p], "lr": 1e-3} for p in params], eps=1e-15, **kind)
        return optimizer.step

    old, new = median_ms(adam(foreach=False), repeats), median_ms(adam(fused=True), repeats)
    out["optimiser: per-tensor Adam -> fused Adam"] = {"old_ms": round(old, 2), "new_ms": round(new, 2),
                                                      "ratio": round(old / new, 2)}
    visible = torch.rand(n, generator=generator) > 0.3
    local = g.local_position.detach().clone().requires_grad_()
    log_scale = g.local_log_scale.detach().clone().requires_grad_()

    def gathered():
        total = losses.position_hinge(local[visible]) + losses.scaling_hinge(log_scale[visible])
        torch.autograd.grad(total, [local, log_scale])

    def masked():
        total = losses.position_hinge(local, mask=visible) + losses.scaling_hinge(log_scale, mask=visible)
        torch.autograd.grad(total, [local, log_scale])

    old, new = median_ms(gathered, repeats), median_ms(masked, repeats)
    out["hinges: gathered rows -> masked mean"] = {"old_ms": round(old, 2), "new_ms": round(new, 2),
                                                  "ratio": round(old / new, 2)}
    grads = torch.randn(n, 2, generator=generator)
    radii = torch.where(visible, torch.randint(1, 9, (n,), generator=generator, dtype=torch.int32), 0)
    strategy = DensifyStrategy(trainer.strategy.schedule, n, len(trainer.avatar.flame.faces))

    def observe_gathered():
        seen = radii > 0
        scaled = grads[seen] * torch.tensor([128.0, 128.0])
        strategy.grad_accum[seen] += scaled.norm(dim=-1)
        strategy.grad_count[seen] += 1
        strategy.max_radii[seen] = torch.maximum(strategy.max_radii[seen], radii[seen].float())

    old = median_ms(observe_gathered, repeats)
    new = median_ms(lambda: strategy.observe(1, grads, radii, 256, 256), repeats)
    out["densification statistics: gathered rows -> whole arrays"] = {
        "old_ms": round(old, 2), "new_ms": round(new, 2), "ratio": round(old / new, 2)}
    return out


def _scene(folder: str, scale: str):
    """``(capture, growth factor or None)``: None grows to about 100k Gaussians (the real scale)."""
    from mogaface.bench.train import _make_capture
    from mogaface.bench.train_real import make_real_capture

    if scale == "real":
        return make_real_capture(folder), None
    return _make_capture(os.path.join(folder, "capture"), 256), 3


def run(threads: int = 2, quick: bool = False, scale: str = "small") -> dict:
    import torch

    from mogaface.bench.grow import grow
    from mogaface.bench.train import _variants
    from mogaface.bench.train_real import HEIGHT, TARGET_GAUSSIANS, WIDTH
    from mogaface.core.train import config as config_module
    from mogaface.core.train.trainer import Trainer

    steps = 5 if quick else 20
    results = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="mogaface-bench-step-") as folder:
        capture, factor = _scene(folder, scale)
        for variant, settings in _variants().items():
            config = config_module.resolve(overrides={
                "train": {"steps": 100000, "threads": threads, "checkpoint_every": 0},
                "densify": {"start": 100000, "stop": 100000, "opacity_reset_interval": 0},
                "eval": {"at_end": False}, **settings})
            trainer = Trainer(capture, os.path.join(folder, variant), config)
            grow(trainer, factor or max(1, round(TARGET_GAUSSIANS / len(trainer.avatar.gaussians))))
            with torch.no_grad():
                trainer.avatar.gaussians.opacity_logit.fill_(2.0)
            for _ in range(3):
                trainer.train_step()
            results.append({"variant": variant, "gaussians": len(trainer.avatar.gaussians), "steps": steps,
                            **profile(trainer, steps)})
            if variant == "freeze":
                changes = path_ratios(trainer, 5 if quick else 20)
            trainer.events.close()
    return {
        "benchmark": "step",
        "scale": scale,
        "threads": threads,
        "image": [WIDTH, HEIGHT] if scale == "real" else [256, 256],
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "results": results,
        "changes_old_vs_new": changes,
    }
