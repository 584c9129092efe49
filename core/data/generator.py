"""The synthetic multi-view capture: the procedural head performing, seen by a camera dome.

Ground truth comes from an independent renderer (never from the splat engine): the mesh
renderer, or Blender's Cycles in child processes (``renderer="cycles"``, :mod:`.cycles_job`). The
capture is written in the GaussianAvatars/VHAP layout with *tracked* parameters (the truth
plus tracker-like noise) in ``flame_param/`` and the truth in ``flame_param_gt/``, so how
well a method recovers the true expressions can be measured. See docs/data-format.md.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import shutil

import numpy as np
import torch

from ..camera import Camera
from ..errors import InputError
from ..flame.expression_roles import mouth_components
from ..flame.landmarks import IBUG_COUNT, model_landmarks
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel
from ..flame.model_file import write_model_file
from ..io.atomic import atomic_path, write_json
from ..io.npz import save_npz
from ..progress import ProgressBar
from . import layout
from .camera_colour import GT_COLOUR_FILE, composite, draw_camera_colours, foreground
from .camera_file import write_cameras
from .capture_info import INFO_FILE
from .capture_settings import CaptureSettings
from .landmarks import write_landmark_file
from .mesh_render import render_mesh, vertex_normals
from .sequences import TEST_SEQUENCE, VAL_SEQUENCE, add_tracking_noise, make_sequences, tracking_biases
from .writer import CaptureWriter

GT_FLAME_DIR = "flame_param_gt"
GT_CAMERAS_FILE = "cameras_gt.json"
BACKGROUND = (1.0, 1.0, 1.0)


def camera_dome(views: int, width: int, vertices: np.ndarray, rng, height: int | None = None
                ) -> tuple[list[Camera], int]:
    """A NeRSemble-like rig: an arc from left to right profile, zig-zagging above and below eye
    level, about 1 m away, with per-camera intrinsics; plus one frontal camera at eye level.
    Images are ``width`` × ``height`` (square without ``height``); the head fills the shorter side.

    Returns the cameras ordered by azimuth and the index of the frontal (held-out) camera.
    """
    height = width if height is None else height
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    extent = float(np.max(vertices.max(0) - vertices.min(0)))
    azimuths = np.linspace(-90.0, 90.0, views - 1)
    elevations = np.array([0.0, 22.0, -16.0])[np.arange(views - 1) % 3]
    placements = sorted([*zip(azimuths, elevations), (0.0, 0.0)], key=lambda p: (p[0], p[1]))
    frontal = placements.index((0.0, 0.0))
    cameras = []
    for index, (azimuth, elevation) in enumerate(placements):
        az, el = np.radians(azimuth), np.radians(elevation)
        distance = 1.0 + rng.normal(scale=0.03)
        direction = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
        target = centre + rng.normal(scale=0.008, size=3)
        fx = 0.85 * min(width, height) * distance / extent * (1.0 + rng.normal(scale=0.02))
        cameras.append(
            Camera.look_at(
                centre + distance * direction,
                target,
                width=width,
                height=height,
                fx=fx,
                fy=fx * (1.0 + rng.normal(scale=0.003)),
                cx=width / 2 + rng.normal(scale=0.012 * width),
                cy=height / 2 + rng.normal(scale=0.012 * height),
                camera_id=f"cam{index:02d}",
            )
        )
    return cameras, frontal


def perturb_camera(camera: Camera, degrees: float, rng, centre_mm: float | None = None) -> Camera:
    """The camera a calibration with ``degrees`` of rotation error (std per axis, about the camera's
    centre) and ``centre_mm`` of centre error (std per axis; default 5 mm per degree) would report."""
    centre_mm = 5.0 * degrees if centre_mm is None else centre_mm
    if degrees == 0 and centre_mm == 0:
        return camera
    delta = np.eye(4)
    rotvec = torch.tensor(rng.normal(scale=np.radians(degrees), size=3))
    delta[:3, :3] = axis_angle_to_matrix(rotvec).numpy()
    delta[:3, 3] = rng.normal(scale=0.001 * centre_mm, size=3)
    return dataclasses.replace(camera, w2c=delta @ camera.w2c)


class LandmarkDetector:
    """A simulated face-landmark detector: the head's 68 iBUG points projected by the *true*
    cameras, with ``landmark_noise`` and ``landmark_bias`` pixels of error; points on surface that
    faces away from a camera get confidence 0. Written as VHAP writes its detector's output.
    It draws from a generator of its own, so the rest of the capture is the same with or without it."""

    def __init__(self, settings: CaptureSettings, model: FlameModel, cameras: list[Camera]):
        self.embedding = model_landmarks(model.arrays.faces)
        self.cameras = cameras
        self.faces = model.arrays.faces
        self.rng = np.random.default_rng([settings.seed, settings.subject, 68])
        self.jitter = settings.landmark_noise
        shape = (len(cameras), IBUG_COUNT, 2)
        self.bias = self.rng.normal(scale=settings.landmark_bias, size=shape)
        self.found: list[list[np.ndarray]] = [[] for _ in cameras]

    def detect(self, vertices, normals) -> None:
        """One timestep: ``vertices`` and ``normals`` of the mesh every camera sees, or a list of
        them, one per camera (unsynchronised cameras each see their own moment)."""
        if self.embedding is None:
            return
        count = len(self.cameras)
        vertices = vertices if isinstance(vertices, list) else [vertices] * count
        normals = normals if isinstance(normals, list) else [normals] * count
        for k, camera in enumerate(self.cameras):
            points = self.embedding.positions(vertices[k], self.faces)
            facing = self.embedding.positions(normals[k], self.faces)
            uv, _ = camera.project(points)
            to_camera = camera.center - points
            seen = np.sum(facing * to_camera, 1) > 0.1 * np.linalg.norm(facing, axis=1) * np.linalg.norm(to_camera, axis=1)
            noisy = uv + self.bias[k] + self.rng.normal(scale=self.jitter, size=uv.shape)
            self.found[k].append(np.concatenate([noisy, seen[:, None].astype(np.float64)], 1))

    def write(self, root: pathlib.Path) -> None:
        if self.embedding is None:
            return
        for camera, rows in zip(self.cameras, self.found):
            write_landmark_file(root, camera.camera_id, np.stack(rows), camera.width, camera.height)


def camera_delays(settings: CaptureSettings, views: int, frontal: int) -> list[float]:
    """Each camera's time offset in timesteps (``camera_delay``; the frontal camera keeps 0), from a
    generator of its own so the rest of the capture is the same with or without them."""
    if settings.camera_delay == 0:
        return [0.0] * views
    delays = np.random.default_rng([settings.seed, settings.subject, 7]).normal(scale=settings.camera_delay, size=views)
    delays[frontal] = 0.0
    return [float(d) for d in delays]


def params_at(params: dict[str, np.ndarray], moment: float) -> dict[str, np.ndarray]:
    """A sequence's parameters at a fractional timestep (linear between its timesteps; its first or
    last beyond its ends)."""
    last = len(params["expr"]) - 1
    moment = float(np.clip(moment, 0, last))
    low = min(int(moment), max(last - 1, 0))
    high = min(low + 1, last)
    weight = np.float32(moment - low)
    return {k: (1 - weight) * v[low] + weight * v[high] for k, v in params.items()}


def moments(sequences, delays: list[float]):
    """Every (timestep, delay) a camera sees, in timestep order: ``(timestep, sequence, local,
    {delay: true parameters at that moment})``."""
    timestep = 0
    for sequence in sequences:
        for local in range(sequence.length):
            truth = {k: v[local] for k, v in sequence.params.items()}
            yield timestep, sequence, local, {
                d: truth if d == 0 else params_at(sequence.params, local + d) for d in sorted(set(delays))}
            timestep += 1


def _write_gt_params(root: pathlib.Path, timestep: int, params: dict[str, np.ndarray]) -> None:
    path = root / GT_FLAME_DIR / f"{timestep:05d}.npz"
    save_npz(path, layout.batched_flame_params(layout.normalize_flame_params(params, path)))


def _model_for(settings: CaptureSettings, out: pathlib.Path, model_path) -> pathlib.Path:
    """Copy the given model, or write the procedural head, into the capture (self-contained)."""
    return write_head_model(out, settings.subject, settings.seed, model_path)


def write_head_model(out: pathlib.Path, subject: int, seed: int, model_path=None) -> pathlib.Path:
    """Copy the given model, or write the procedural head of ``subject``, into ``out``; its path."""
    if model_path is not None:
        model_path = pathlib.Path(model_path)
        target = out / f"head{model_path.suffix}"
        with atomic_path(target) as tmp:
            shutil.copyfile(model_path, tmp)
        return target
    from ..flame.procedural import build_head

    target = out / "head.pkl"
    write_model_file(target, build_head(subject=subject, seed=seed))
    return target


def make_capture(
    out: str | os.PathLike,
    settings: CaptureSettings = CaptureSettings(),
    model_path: str | os.PathLike | None = None,
    progress: bool = True,
    threads: int | None = None,
    render_part: tuple[int, int] = (1, 1),
) -> pathlib.Path:
    """Render and write a synthetic capture into ``out``; returns the folder. ``threads``: Cycles'
    render threads (default: all cores). ``render_part`` (K, N) other than (1, 1): render only this
    machine's share of Cycles' images into ``out/.cycles/renders`` and write no capture (the
    shares' images gathered there, a run without it writes the capture)."""
    settings.check()
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    head_file = _model_for(settings, out, model_path)
    model = FlameModel.load(head_file)
    arrays = model.arrays
    if arrays.vt is None or arrays.texture is None:
        raise InputError(head_file, "vt/ft/texture", "a synthetic capture needs a model with UVs and a texture")
    texture = arrays.texture.astype(np.float32) / 255.0

    rng = np.random.default_rng([settings.seed, settings.subject])
    with torch.no_grad():
        rest = model()[0].double().numpy()
    cameras, frontal = camera_dome(settings.views, settings.size, rest, rng, settings.image_height)
    reported = [perturb_camera(c, settings.camera_noise, rng, settings.camera_centre_noise) for c in cameras]
    sequences = make_sequences(settings.timesteps, model.n_shape, model.n_expr, mouth_components(arrays),
                               seed=settings.seed + 7919 * settings.subject)
    noise = settings.tracking_noise()
    biases = tracking_biases(sequences[0].params, noise, rng)  # one tracker, one bias per capture

    delays = camera_delays(settings, len(cameras), frontal)
    colours = draw_camera_colours(len(cameras), settings.camera_colour,
                                  np.random.default_rng([settings.seed, settings.subject, 11]))
    detector = LandmarkDetector(settings, model, cameras)
    if settings.renderer == "cycles":
        from .cycles_job import render_with_cycles

        cycles = render_with_cycles(out, model, cameras, moments(sequences, delays), delays, settings,
                                    threads=threads, progress=progress, part=render_part)
        if render_part != (1, 1):
            return out
    total = sum(s.length for s in sequences)
    bar = ProgressBar(total * len(cameras), "make-capture") if progress else None
    ranges = {}
    with CaptureWriter(out, n_vertices=model.n_vertices) as writer:
        for timestep, sequence, local, at in moments(sequences, delays):
            if local == 0:
                tracked = add_tracking_noise(sequence.params, noise, rng, biases)
                ranges[sequence.name] = [timestep, timestep + sequence.length]
            writer.write_flame_params(timestep, {k: v[local] for k, v in tracked.items()})
            _write_gt_params(out, timestep, at[0.0])  # the frontal camera keeps the rig's clock
            seen = {}  # moment → (vertices, normals): shared by the views that see it
            for delay, params in at.items():
                posed = model.posed(params)
                seen[delay] = (posed, vertex_normals(posed, arrays.faces))
            detector.detect([seen[d][0] for d in delays], [seen[d][1] for d in delays])
            for index, (camera, written) in enumerate(zip(cameras, reported)):
                if settings.renderer == "cycles":
                    linear, alpha = cycles.image(timestep, index)
                    rgb = composite(colours[index].seen(linear), alpha, BACKGROUND)
                else:
                    vertices, normals = seen[delays[index]]
                    rgb, alpha = render_mesh(
                        vertices, arrays.faces, arrays.vt, arrays.ft, texture, camera, BACKGROUND,
                        supersample=settings.supersample, normals=normals,
                    )
                    if settings.camera_colour:
                        rgb = composite(colours[index].seen(foreground(rgb, alpha, BACKGROUND)), alpha, BACKGROUND)
                held_out = sequence.name in (TEST_SEQUENCE, VAL_SEQUENCE)  # never trained on: the test split
                split = "test" if held_out else ("val" if index == frontal else "train")
                writer.add_frame(
                    timestep, written, rgb, alpha, split=split, sequence=sequence.name,
                    timestep_id=f"{sequence.name}_{local:04d}", camera_index=index,
                )
                if bar:
                    bar.update()
        zeros = {k: np.zeros_like(v[0]) for k, v in sequences[0].params.items()}
        writer.write_canonical_flame_params(zeros)
    detector.write(out)
    write_cameras(out / GT_CAMERAS_FILE, {c.camera_id: c for c in cameras})
    if settings.camera_colour:
        write_json(out / GT_COLOUR_FILE, {c.camera_id: dataclasses.asdict(k) for c, k in zip(cameras, colours)})
    write_json(
        out / INFO_FILE,
        {
            "generator": "mogaface make-capture",
            "settings": dataclasses.asdict(settings),
            "model_file": head_file.name,
            "background": list(BACKGROUND),
            "val_camera": cameras[frontal].camera_id,
            "test_sequence": TEST_SEQUENCE,
            "val_sequence": VAL_SEQUENCE,
            "sequences": ranges,
            "ground_truth": {"flame_param": GT_FLAME_DIR, "cameras": GT_CAMERAS_FILE,
                             **({"camera_colour": GT_COLOUR_FILE} if settings.camera_colour else {})},
            **({"camera_delays": {c.camera_id: d for c, d in zip(cameras, delays)}} if any(delays) else {}),
        },
    )
    if settings.renderer == "cycles":
        cycles.finish()
    return out
