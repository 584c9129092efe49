"""Synthetic captures rendered by Cycles: the job a child process renders, and its images read back.

``make-capture --renderer cycles`` writes a job into ``OUT/.cycles/`` (the head's surface maps,
hair strands, light rig, cameras, and the posed mesh of every moment a camera sees), then runs
``python -m mogaface.cycles_capture`` (the bpy layer's renderer, :mod:`mogaface.cycles_capture`) as a child
process with the same Python, which must have the ``bpy`` module. The child renders one EXR (linear,
premultiplied RGBA) per image, each written under a temporary name and renamed, and skips the
images already there: an interrupted capture resumes by running the same command again. The
generator then reads the images back, applies each camera's colour and writes the capture as the
mesh renderer's are written; the job folder goes when the capture is complete.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np

from ..errors import CaptureError, InputError
from ..flame.landmarks import model_landmarks
from ..io.atomic import write_json
from ..io.image import read_image
from ..io.npz import save_npz
from ..progress import ProgressBar
from .camera_file import write_cameras
from .cycles_hair import grow_strands
from .cycles_skin import MATERIALS, SKIN, WrinkleDriver, face_materials, surface_maps

JOB_DIR = ".cycles"
CHILD_MODULE = "mogaface.cycles_capture"
# A capture dome's soft boxes around the head (FLAME axes: x across, y up, z toward the face):
# (direction from the head, distance m, size m, power W). A key and a fill in front, one above,
# two behind for the rim; the surroundings a dim grey.
LIGHT_RIG = (
    ((0.55, 0.45, 1.0), 1.3, 0.8, 16.0),
    ((-0.8, 0.15, 0.8), 1.4, 1.0, 6.0),
    ((0.0, 1.0, 0.25), 1.3, 1.0, 6.0),
    ((0.9, 0.35, -0.8), 1.2, 0.6, 8.0),
    ((-0.9, 0.35, -0.8), 1.2, 0.6, 8.0),
)
WORLD_GREY = 0.06
# The denoiser takes the albedo and normal passes as rendered ("FAST"), not denoised first
# ("ACCURATE", Cycles' default): at 802×550 and 32 samples that costs 1.1 dB of noise and saves
# 3.1 of 11.8 s an image, more than halving the samples does (docs/data-format.md).
DENOISING_PREFILTER = "FAST"


def moment_name(timestep: int, delay: float) -> str:
    return f"{timestep:05d}_{delay:+.4f}"


def image_name(timestep: int, camera_index: int) -> str:
    return f"{timestep:05d}_{camera_index:02d}.exr"


def map_size(settings) -> int:
    """Texels a side of the wrinkle and roughness maps: about four per image pixel across the
    image's longer side (1024 at 256²), at least 256, at most 2048."""
    longest = max(settings.size, settings.image_height)
    return int(np.clip(2 ** np.ceil(np.log2(4 * longest)), 256, 2048))


def check_bpy() -> None:
    """Refuse early, naming what is missing, when this Python cannot run the renderer."""
    if importlib.util.find_spec("bpy") is None:
        raise InputError(None, "renderer", "cycles needs the bpy module in this Python (pip install bpy==5.0.1, "
                                           "Python 3.11; the project's venv has it)")


def write_job(root: pathlib.Path, model, cameras, moments, delays, settings) -> list[dict]:
    """Write the job into ``root``; its frames (the images to render, in render order)."""
    arrays = model.arrays
    fingerprint = dataclasses.asdict(settings)
    job_file = root / "job.json"
    if job_file.exists() and json.loads(job_file.read_text()).get("settings") != fingerprint:
        shutil.rmtree(root)  # another capture's job: nothing of it may be reused
    (root / "moments").mkdir(parents=True, exist_ok=True)
    rest = model.posed({})
    marks = model_landmarks(arrays.faces).positions(rest, arrays.faces)
    maps = surface_maps(arrays, rest, marks, map_size(settings))
    materials = face_materials(arrays)
    strands = grow_strands(arrays, rest, maps["texel_face"], maps["texel_bary"], marks, materials == SKIN,
                           np.random.default_rng([settings.seed, settings.subject, 5]))
    save_npz(root / "scene.npz", {
        "faces": arrays.faces, "vt": arrays.vt, "ft": arrays.ft, "texture": arrays.texture,
        "material": materials, "wrinkles": maps["wrinkles"].astype(np.float16),
        "roughness": maps["roughness"].astype(np.float16), **strands.arrays(),
    })
    write_cameras(root / "cameras.json", {c.camera_id: c for c in cameras})
    driver = WrinkleDriver(arrays, rest)
    frames = []
    for timestep, _, _, at in moments:
        for delay, params in at.items():
            name = moment_name(timestep, delay)
            path = root / "moments" / f"{name}.npz"
            if not path.exists():
                save_npz(path, {"vertices": model.posed(params).astype(np.float32),
                                "wrinkle": driver.weights(params.get("expr", np.zeros(0)))})
            frames += [{"moment": name, "camera": k, "image": image_name(timestep, k)}
                       for k, d in enumerate(delays) if d == delay]
    centre = 0.5 * (rest.min(0) + rest.max(0))
    write_json(job_file, {
        "settings": fingerprint, "samples": settings.samples, "denoising_prefilter": DENOISING_PREFILTER,
        "seed": settings.seed, "materials": list(MATERIALS),
        "lights": [{"position": list(centre + distance * np.asarray(d) / np.linalg.norm(d)),
                    "target": list(centre), "size": size, "power": power}
                   for d, distance, size, power in LIGHT_RIG],
        "world_grey": WORLD_GREY, "frames": frames,
    })
    return frames


def parse_part(text: str) -> tuple[int, int]:
    """``"K/N"`` (one machine's share of a job: the K-th of N) → ``(K, N)``, checked."""
    try:
        share, shares = (int(v) for v in text.split("/"))
    except ValueError:
        share = shares = 0
    if not 1 <= share <= shares:
        raise InputError(None, "render part", f"expected K/N with 1 <= K <= N (e.g. 1/3), got {text!r}")
    return share, shares


def in_part(frames: list[dict], part: tuple[int, int]) -> list[bool]:
    """Which of a job's ``frames`` fall in ``part`` (K, N): every N-th moment from the K-th, in render
    order, so that each machine poses each of its moments once."""
    order = list(dict.fromkeys(f["moment"] for f in frames))
    mine = set(order[part[0] - 1::part[1]])
    return [f["moment"] in mine for f in frames]


def run_child(root: pathlib.Path, threads: int | None, progress: bool, part: tuple[int, int] = (1, 1)) -> int:
    """Run the renderer on the job in ``root`` with a progress bar; how many images it rendered
    (those already there are kept). ``part`` (K, N): only the K-th of N shares of the job's
    moments, one machine's. Ctrl-C stops it and keeps what it rendered; a failure raises with the
    child's last lines."""
    command = [sys.executable, "-m", CHILD_MODULE, os.fspath(root), "--threads", str(threads or 0),
               "--part", f"{part[0]}/{part[1]}"]
    frames = json.loads((root / "job.json").read_text())["frames"]
    mine = in_part(frames, part)
    done = sum(m and (root / "renders" / f["image"]).exists() for f, m in zip(frames, mine))
    bar = ProgressBar(sum(mine), "make-capture (cycles)") if progress else None
    if bar:
        bar.update(done)
    tail: list[str] = []
    rendered = 0
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        for line in child.stdout:
            if line.startswith('{"event"'):
                event = json.loads(line)
                rendered += event["event"] == "rendered"
                if bar and event["event"] == "rendered":
                    bar.update(1, f"{event['seconds']:.1f} s/image")
            else:
                tail = (tail + [line.rstrip()])[-20:]
        code = child.wait()
    except KeyboardInterrupt:
        child.terminate()
        child.wait()
        print(f"\nstopped; the images rendered so far are kept in {root}: run the same command to resume",
              file=sys.stderr)
        raise
    if code != 0:
        raise CaptureError(root, "renderer", "the Cycles renderer failed:\n" + "\n".join(tail))
    return rendered


class CyclesImages:
    """The rendered images of a job, read back as (linear foreground (H,W,3), coverage (H,W))."""

    def __init__(self, root: pathlib.Path):
        self.root = root

    def image(self, timestep: int, camera_index: int) -> tuple[np.ndarray, np.ndarray]:
        rgba = read_image(self.root / "renders" / image_name(timestep, camera_index))
        alpha = np.clip(rgba[..., 3], 0.0, 1.0)
        linear = np.where(alpha[..., None] > 1e-4, rgba[..., :3] / np.maximum(alpha[..., None], 1e-4), 0.0)
        return np.maximum(linear, 0.0).astype(np.float32), alpha

    def finish(self) -> None:
        """The capture is written: the job and its images go."""
        shutil.rmtree(self.root, ignore_errors=True)


def render_with_cycles(out: pathlib.Path, model, cameras, moments, delays, settings, *,
                       threads: int | None = None, progress: bool = True,
                       part: tuple[int, int] = (1, 1)) -> CyclesImages:
    """Render every image of a capture with Cycles (resuming a job already under ``out``), or
    with ``part`` (K, N) this machine's share of them."""
    check_bpy()
    root = out / JOB_DIR
    write_job(root, model, cameras, moments, delays, settings)
    run_child(root, threads, progress, part)
    return CyclesImages(root)
