"""Cameras from 2D landmarks: turn each training camera about its centre so that the head model's
landmarks, on the tracked mesh, land where the detector found them in every view.

Why: a calibration that is off by a degree leaves refinement from the images alone at about 70 %
of the novel view it costs (docs/results.md): cameras that see the same side of the face turn
together and carry the avatar's face with them. Landmarks are information from outside the images
the avatar learns from; started from the cameras they give, refinement ends nearer the truth.

The adjustment (L-BFGS, Huber loss on pixel residuals): a rotation ``ω`` per camera about its own
centre (centres are held, as refinement holds them: the images pin them only by parallax), and a
rigid correction of every timestep's tracked mesh (the tracker's head pose is off too). Nothing
holds the head at the tracked position: a shift of the head and a turn of every camera toward it
then differ only by perspective, and the cameras may aim a few tenths of a degree off; refinement
takes that out from the images, and a prior of a millimetre on the shift, which aimed them right,
scored 0.8 dB lower after refinement (docs/results.md). Then the
refinement's gauge (``rigid`` by default) is applied, so the result starts ``[cameras] refine``
exactly as an earlier round's cameras would.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..camera import Camera
from ..data.capture import Capture
from ..data.landmarks import read_landmarks
from ..errors import InputError
from ..flame.landmarks import STATIC_IBUG, LandmarkEmbedding, model_landmarks
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel
from .camera_refine import CameraOffsets
from .config import CAMERA_GAUGES
from .data import FlameTable

HUBER_FRACTION = 0.01  # the Huber loss's knee, as a fraction of the image width (1.3 px at 128²)
MIN_LANDMARKS = 20  # weighted observations a camera needs to be turned
LANDMARK_CAMERAS_FILE = "cameras_landmarks.json"  # beside a run that started from them


@dataclasses.dataclass
class LandmarkCameras:
    cameras: dict[str, Camera]  # every training camera, turned (or kept) and the gauge applied
    report: dict  # per camera: landmarks used, rotation (degrees), RMS before/after (pixels)


def training_cameras(capture: Capture, split: str = "train") -> dict[str, Camera]:
    """Each training camera, refusing one that moves between frames (no single turn fits it)."""
    cameras: dict[str, Camera] = {}
    for frame in capture.frames(split):
        camera = capture.camera(frame)
        known = cameras.setdefault(frame.camera_id, camera)
        if not np.allclose(known.w2c, camera.w2c, atol=1e-9):
            raise InputError(capture.root, frame.camera_id,
                             "the camera moves between frames; cameras from landmarks need fixed cameras")
    return cameras


def solve_cameras(capture: Capture, head_file, embedding: LandmarkEmbedding | None = None, *,
                  points=STATIC_IBUG, gauge: str = CAMERA_GAUGES[0], split: str = "train") -> LandmarkCameras:
    """Turn the capture's ``split`` cameras to fit its landmark files (``landmark2d/``).
    ``embedding``: where the landmarks lie on ``head_file``'s mesh (the procedural head's own when
    None; a FLAME model needs its embedding file)."""
    cameras = training_cameras(capture, split)
    timesteps = sorted({f.timestep_index for f in capture.frames(split)})
    table = FlameTable(timesteps, capture.flame_params_stacked(timesteps))
    model = FlameModel.load(head_file, n_vertices=table.n_vertices)
    if embedding is None:
        embedding = model_landmarks(model.faces.numpy())
        if embedding is None:
            raise InputError(head_file, None, "no landmark embedding for this head model: pass FLAME's "
                                              "(landmark_embedding_with_eyes.npy or flame_static_embedding.pkl)")
    found = read_landmarks(capture.root, cameras, max(timesteps) + 1)
    if not found:
        raise InputError(capture.root / "landmark2d", None, "no landmark file for any training camera "
                                                            "(expected landmark2d/STAR/<camera id>.npz, docs/data-format.md)")
    embedding = embedding.subset(np.asarray(points)).check(len(model.faces), "landmark embedding")
    ids = sorted(found)
    shown = {(f.camera_id, f.timestep_index) for f in capture.frames(split)}
    observed = np.stack([found[c][timesteps][:, embedding.ibug] for c in ids])  # (C,T,L,3)
    observed[..., 2] *= np.array([[(c, t) in shown for t in timesteps] for c in ids], np.float64)[..., None]
    with torch.no_grad():
        landmarks = embedding.positions(model(**table.params()).double(), model.faces)  # (T,L,3)
    problem = _Adjustment([cameras[c] for c in ids], landmarks, torch.as_tensor(observed))
    before = problem.rms_by_camera()
    problem.solve()
    after = problem.rms_by_camera()
    offsets = CameraOffsets(cameras, gauge)
    with torch.no_grad():
        for k, camera_id in enumerate(ids):
            offsets.rotation[offsets.index[camera_id]].copy_(problem.turn[k].float())
    offsets.fix_gauge()
    report = {cid: {"landmarks": int(problem.count[k]), "rms_before_px": before[k], "rms_after_px": after[k],
                    "turned": bool(problem.count[k] >= MIN_LANDMARKS),
                    "rotation_deg": float(np.degrees(offsets.rotation[offsets.index[cid]].detach().norm()))}
              for k, cid in enumerate(ids)}
    return LandmarkCameras(offsets.refined_cameras(), report)


class _Adjustment:
    """The least-squares problem: camera turns ``turn`` (C,3), mesh turns ``head_turn`` and shifts
    ``head_shift`` (T,3) about each timestep's landmark centroid."""

    def __init__(self, cameras: list[Camera], landmarks: torch.Tensor, observed: torch.Tensor):
        self.rotation = _stacked([c.w2c[:3, :3] for c in cameras])
        self.centre = _stacked([c.center for c in cameras])
        self.focal = _stacked([[c.fx, c.fy] for c in cameras])
        self.principal = _stacked([[c.cx, c.cy] for c in cameras])
        self.knee = HUBER_FRACTION * float(np.mean([c.width for c in cameras]))
        self.landmarks = landmarks
        self.centroid = landmarks.mean(1, keepdim=True)
        self.target = observed[..., :2]
        self.weight = observed[..., 2]
        self.count = self.weight.sum((1, 2)).numpy()
        self.weight = self.weight * torch.as_tensor(self.count >= MIN_LANDMARKS, dtype=torch.float64)[:, None, None]
        count, steps = len(cameras), len(landmarks)
        self.turn = torch.zeros(count, 3, dtype=torch.float64, requires_grad=True)
        self.head_turn = torch.zeros(steps, 3, dtype=torch.float64, requires_grad=True)
        self.head_shift = torch.zeros(steps, 3, dtype=torch.float64, requires_grad=True)

    def residual(self) -> torch.Tensor:
        """(C,T,L,2) pixel residuals."""
        head = axis_angle_to_matrix(self.head_turn)
        points = (self.landmarks - self.centroid) @ head.transpose(1, 2) + self.centroid + self.head_shift[:, None]
        # a camera turned by exp(ω) about its centre sees X as the calibrated one sees exp(−ω)(X − c) + c
        undo = axis_angle_to_matrix(-self.turn)
        relative = torch.einsum("cij,ctlj->ctli", undo, points[None] - self.centre[:, None, None])
        camera = torch.einsum("cij,ctlj->ctli", self.rotation, relative)
        pixels = camera[..., :2] / camera[..., 2:3] * self.focal[:, None, None] + self.principal[:, None, None]
        return pixels - self.target

    def loss(self) -> torch.Tensor:
        distance = self.residual().norm(dim=-1)
        huber = torch.where(distance < self.knee, 0.5 * distance**2, self.knee * (distance - 0.5 * self.knee))
        return (huber * self.weight).sum() / self.weight.sum().clamp_min(1.0)

    def solve(self, rounds: int = 5) -> None:
        if float(self.weight.sum()) == 0:
            return
        variables = [self.turn, self.head_turn, self.head_shift]
        optimiser = torch.optim.LBFGS(variables, lr=1, max_iter=200, line_search_fn="strong_wolfe",
                                      tolerance_grad=1e-10, tolerance_change=1e-14)

        def closure():
            optimiser.zero_grad()
            value = self.loss()
            value.backward()
            return value

        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # small tensors: a second thread only waits, badly so on a busy machine
        try:
            for _ in range(rounds):
                optimiser.step(closure)
        finally:
            torch.set_num_threads(threads)

    @torch.no_grad()
    def rms_by_camera(self) -> list[float]:
        squared = (self.residual() ** 2).sum(-1)
        totals = self.weight.sum((1, 2))
        return [float(torch.sqrt((squared[k] * self.weight[k]).sum() / totals[k])) if totals[k] > 0 else float("nan")
                for k in range(len(totals))]


def _stacked(rows) -> torch.Tensor:
    return torch.as_tensor(np.stack(rows), dtype=torch.float64)
