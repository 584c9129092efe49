"""Benchmark of Cycles captures (``make-capture --renderer cycles``): seconds per image, and noise.

Speed: the default capture's head at one moment, seen by the dome's cameras, rendered by the same
child process ``make-capture`` runs, at 256², 512² and 802×550 (NeRSemble's size), with the default
samples: seconds per image (median over the cameras; the first image of a moment also poses the
head), the child's start, and what a whole capture then takes (the default capture's 2 400 images
at 256²; a real-scale one, 16 cameras × 400 timesteps at 802×550, as ``bench converge`` trains);
and the real-scale size again at 8 and 16 samples, the noise below telling what they cost.
The denoiser's prefilter at that size: seconds an image and noise at 16 and 32 samples with the
albedo and normal passes as rendered (``FAST``, the captures') or denoised first (``ACCURATE``).

Noise: the frontal camera at 256² rendered with 8, 16, 32 and 64 samples (denoised) against a
1 024-sample reference, PSNR on the head's pixels (sRGB): the noise must sit well below the
avatar's own error (its novel-view PSNR on these captures is about 30 dB), so the avatar is never
asked to fit noise. ``--quick``: 64² images, a 64-sample reference (a smoke run).
"""

from __future__ import annotations

import json
import os
import pathlib
import statistics
import tempfile
import time

SIZES = ((256, 256), (512, 512), (802, 550))
SAMPLES = (8, 16, 32, 64)
REFERENCE_SAMPLES = 1024
CAMERAS = 4  # images timed per size
PREFILTER_SAMPLES = (16, 32)
PREFILTERS = ("FAST", "ACCURATE")  # the denoiser's albedo and normal passes as rendered, or denoised first
MOMENT = 75  # a timestep mid-capture (an expression, the mouth open a little)


def _job(folder: pathlib.Path, label: str, width: int, height: int, samples: int, cameras: int, repeat: int = 1,
         prefilter: str | None = None):
    """A job of one moment seen by ``cameras`` of the dome (each ``repeat`` times, own noise),
    denoised with ``prefilter`` (default: the captures')."""
    import numpy as np

    from mogaface.core.data import generator
    from mogaface.core.data.capture_settings import CaptureSettings
    from mogaface.core.data.cycles_job import write_job
    from mogaface.core.data.sequences import make_sequences
    from mogaface.core.flame.expression_roles import mouth_components
    from mogaface.core.flame.model import FlameModel

    settings = CaptureSettings(size=width, height=None if width == height else height, renderer="cycles",
                               samples=samples)
    model = FlameModel.load(generator.write_head_model(folder, settings.subject, settings.seed))
    rest = model.posed({})
    dome, frontal = generator.camera_dome(settings.views, width, rest, np.random.default_rng(0), settings.image_height)
    order = [frontal] + [k for k in range(len(dome)) if k != frontal]
    chosen = [dome[k] for k in order[:cameras]]
    sequences = make_sequences(settings.timesteps, model.n_shape, model.n_expr, mouth_components(model.arrays),
                               seed=settings.seed)
    moment = [m for m in generator.moments(sequences, [0.0] * len(chosen)) if m[0] == MOMENT]
    root = folder / f"{label}_{width}x{height}_{samples}_{prefilter}"
    frames = write_job(root, model, chosen, moment, [0.0] * len(chosen), settings)
    job = json.loads((root / "job.json").read_text())
    job["frames"] = [dict(f, image=f"r{r}_{f['image']}") for r in range(repeat) for f in frames]
    job["denoising_prefilter"] = prefilter or job["denoising_prefilter"]
    (root / "job.json").write_text(json.dumps(job))
    return root


def _render(root: pathlib.Path, threads: int) -> list[float]:
    """Seconds of each image the child rendered, and the child's whole time first."""
    import subprocess
    import sys

    from mogaface.core.data.cycles_job import CHILD_MODULE

    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", CHILD_MODULE, os.fspath(root), "--threads", str(threads)],
                          capture_output=True, text=True, check=True)
    seconds = [json.loads(line)["seconds"] for line in done.stdout.splitlines() if line.startswith('{"event"')]
    return [time.monotonic() - start] + seconds


def _foreground_psnr(image, reference) -> float:
    import numpy as np

    from mogaface.core.io.image import linear_to_srgb, read_image

    a, b = read_image(image), read_image(reference)
    covered = b[..., 3] > 0.5
    error = np.mean((linear_to_srgb(a[..., :3])[covered] - linear_to_srgb(b[..., :3])[covered]) ** 2)
    return float(10 * np.log10(1.0 / max(error, 1e-12)))


def _denoising(folder: pathlib.Path, size: tuple[int, int], threads: int, quick: bool) -> dict:
    """The denoiser's prefilter at the real-scale size: seconds an image and noise (as above, the
    frontal camera against a reference) at 16 and 32 samples, each prefilter."""
    reference = _job(folder, "denoise_reference", *size, 64 if quick else REFERENCE_SAMPLES, 1)
    _render(reference, threads)
    reference_image = next((reference / "renders").glob("*.exr"))
    table = {}
    for samples in PREFILTER_SAMPLES:
        for prefilter in PREFILTERS:
            root = _job(folder, "denoise", *size, samples, 1, repeat=2, prefilter=prefilter)
            _, *each = _render(root, threads)
            table[f"{samples}_{prefilter}"] = {
                "samples": samples, "prefilter": prefilter, "seconds_per_image": round(each[-1], 2),
                "psnr_vs_reference_db": round(_foreground_psnr(sorted((root / "renders").glob("*.exr"))[0],
                                                                reference_image), 2)}
    return table


def run(threads: int = 2, quick: bool = False) -> dict:
    load_before = os.getloadavg()
    sizes = ((64, 64),) if quick else SIZES
    speed = {}
    with tempfile.TemporaryDirectory(prefix="bench_cycles_") as tmp:
        folder = pathlib.Path(tmp)
        from mogaface.core.data.capture_settings import CaptureSettings

        default = CaptureSettings()
        for width, height in sizes:
            total, *each = _render(_job(folder, "speed", width, height, default.samples, CAMERAS), threads)
            speed[f"{width}x{height}"] = {
                "seconds_per_image": round(statistics.median(each[1:] or each), 2),
                "first_image_s": round(each[0], 2), "child_total_s": round(total, 1),
                "child_start_s": round(total - sum(each), 1), "images": len(each)}
        largest = sizes[-1]
        fewer = {}  # the real-scale size at fewer samples: what an overnight capture takes
        for samples in (s for s in SAMPLES if s < default.samples):
            _, *each = _render(_job(folder, "fewer", *largest, samples, CAMERAS), threads)
            fewer[samples] = round(statistics.median(each[1:] or each), 2)
        side = sizes[0]
        reference_samples = 64 if quick else REFERENCE_SAMPLES
        reference = _job(folder, "reference", *side, reference_samples, 1, repeat=2)
        _render(reference, threads)
        reference_image = sorted((reference / "renders").glob("*.exr"))[1]  # another noise than the first images'
        noise = {}
        for samples in SAMPLES:
            root = _job(folder, "noise", *side, samples, 1, repeat=2)
            _render(root, threads)
            first, second = sorted((root / "renders").glob("*.exr"))
            noise[samples] = {"psnr_vs_reference_db": round(_foreground_psnr(first, reference_image), 2),
                              "psnr_between_two_seeds_db": round(_foreground_psnr(first, second), 2)}
        denoising = _denoising(folder, largest, threads, quick)
    per_image = speed[f"{largest[0]}x{largest[1]}"]["seconds_per_image"]
    small = speed[f"{sizes[0][0]}x{sizes[0][1]}"]["seconds_per_image"]
    real_scale = 16 * 400 / 3600  # hours a real-scale capture takes per second an image
    return {
        "benchmark": "cycles",
        "threads": threads,
        "samples": default.samples,
        "speed": speed,
        "noise_at": f"{side[0]}x{side[1]}",
        "reference_samples": reference_samples,
        "noise": noise,
        "default_capture_hours": round(small * default.views * default.timesteps / 3600, 2),
        "real_scale_capture_hours": round(per_image * real_scale, 2),
        "real_scale_fewer_samples": {samples: {"seconds_per_image": seconds, "capture_hours": round(seconds * real_scale, 2)}
                                     for samples, seconds in fewer.items()},
        "denoising_at": f"{largest[0]}x{largest[1]}",
        "denoising": denoising,
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
