"""Which way a capture's ``cy`` is measured, judged from its masks and its tracked mesh.

The split files may measure ``cy`` from the bottom edge (VHAP's exporter; our default) or
from the top (``"cy_origin": "top"``). The two readings differ by ``h − 2·cy`` pixels
vertically, which nothing in the json reveals. The tracked FLAME mesh does: projected with
the right reading, its vertices fall inside the foreground masks; with the mirrored one,
those near the silhouette fall out. This compares the two readings on a spread of frames and
decides only when the difference stands out of its frame-to-frame spread: a calibration a degree
off moves the mesh by more pixels than a principal point a few pixels off centre, and on four
frames such a capture read "mirrored" by chance.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import numpy as np

from ..camera import Camera
from .capture import Capture

MARGIN = 0.003  # the smallest difference in mean mask coverage that decides
SIGNIFICANCE = 3.0  # ... and it must be this many standard errors of the per-frame differences
FRAMES = 24  # frames compared, spread over the capture


@dataclasses.dataclass
class CyReport:
    declared: str  # "bottom" or "top": how the reader reads the files
    verdict: str  # "confirmed", "mirrored", "undecided", "centred" or "unchecked"
    coverage: tuple[float, float] | None = None  # mean mask value at the vertices: (as read, mirrored)
    reason: str = ""

    def line(self) -> str:
        read = {"bottom": "from the bottom edge (VHAP's convention)", "top": "from the top edge"}[self.declared]
        text = f"cy: read {read}"
        if self.coverage is not None:
            text += f"; tracked mesh inside the masks: {self.coverage[0]:.3f} as read, {self.coverage[1]:.3f} mirrored"
        return f"{text}; {self.verdict}" + (f" ({self.reason})" if self.reason else "")


def mirrored(camera: Camera) -> Camera:
    """The same camera with its principal point's y read from the other edge."""
    K = camera.K.copy()
    K[1, 2] = camera.height - K[1, 2]
    return dataclasses.replace(camera, K=K)


def mask_coverage(vertices: np.ndarray, camera: Camera, mask: np.ndarray) -> float:
    """Mean mask value at the pixels the vertices project to (vertices outside the image count 0)."""
    cam = vertices @ camera.w2c[:3, :3].T + camera.w2c[:3, 3]
    front = cam[:, 2] > 1e-6
    u = camera.fx * cam[front, 0] / cam[front, 2] + camera.cx
    v = camera.fy * cam[front, 1] / cam[front, 2] + camera.cy
    col, row = np.floor(u).astype(int), np.floor(v).astype(int)
    inside = (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    values = np.zeros(len(vertices))
    values[np.flatnonzero(front)[inside]] = mask[row[inside], col[inside]]
    return float(values.mean())


def check_cy(capture: Capture, head, max_frames: int = FRAMES) -> CyReport:
    """Compare the two readings of ``cy`` on up to ``max_frames`` frames (needs the head model: its
    file, or the model already loaded for the capture's tracking, as training has it)."""
    import torch

    from ..flame.model import FlameModel

    declared = capture.declared_cy_origin
    frames = capture.frames()
    if all(abs(2 * capture.camera(f).cy - capture.camera(f).height) < 1e-6 for f in frames):
        return CyReport(declared, "centred", reason="every principal point is at the image centre: both readings agree")
    given_file = isinstance(head, (str, os.PathLike))
    if head is None or given_file and not pathlib.Path(head).is_file():
        return CyReport(declared, "unchecked", reason="no head model to project (pass --head FLAME_MODEL)")
    picks = [frames[i] for i in np.unique(np.linspace(0, len(frames) - 1, max_frames).round().astype(int))]
    params = [capture.flame_params(f.timestep_index) for f in picks]
    offsets = [p[k] for p in params for k in ("static_offset", "dynamic_offset") if k in p]
    model = FlameModel.load(head, n_vertices=offsets[0].shape[0] if offsets else None) if given_file else head
    as_read, other = [], []
    with torch.no_grad():
        for frame, p in zip(picks, params):
            tensors = {k: torch.as_tensor(np.asarray(v, dtype=np.float32))[None] for k, v in p.items()}
            vertices = model(**tensors)[0].double().numpy()
            mask = capture.load_image(frame)[1]
            as_read.append(mask_coverage(vertices, capture.camera(frame), mask))
            other.append(mask_coverage(vertices, mirrored(capture.camera(frame)), mask))
    return judge(declared, as_read, other)


def judge(declared: str, as_read, other) -> CyReport:
    """The verdict from per-frame mask coverages under the declared and the mirrored reading."""
    difference = np.asarray(as_read, np.float64) - np.asarray(other, np.float64)
    coverage = (float(np.mean(as_read)), float(np.mean(other)))
    spread = float(difference.std(ddof=1) / np.sqrt(len(difference))) if len(difference) > 1 else 0.0
    if abs(difference.mean()) <= max(MARGIN, SIGNIFICANCE * spread):
        return CyReport(declared, "undecided", coverage,
                        f"the masks do not tell the readings apart on {len(difference)} frames: the difference is "
                        "within its spread from frame to frame, as when the calibration or the tracking is off "
                        "by more than the principal point is off centre")
    if difference.mean() > 0:
        return CyReport(declared, "confirmed", coverage)
    fix = '"cy_origin": "top"' if declared == "bottom" else 'no "cy_origin" key (or "bottom")'
    return CyReport(declared, "mirrored", coverage, f"the masks fit the other reading: give the split files {fix}")
