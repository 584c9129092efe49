"""Cameras from 2D landmarks: turn each training camera about its centre so that the head model's
landmarks, on the tracked mesh, land where the detector found them in every view.

Why: a calibration that is off by a degree leaves refinement from the images alone at about 70 %
of the novel view it costs (docs/notebook/2026-11-26-camera-refinement.md): cameras that see the
same side of the face turn together and carry the avatar's face with them. Landmarks are
information from outside the images the avatar learns from; started from the cameras they give,
refinement ends nearer the truth.

The adjustment (L-BFGS, Huber loss on pixel residuals): a rotation ``ω`` per camera about its own
centre (centres are held, as refinement holds them: the images pin them only by parallax), and a
rigid correction of every timestep's tracked mesh (the tracker's head pose is off too). Nothing
holds the head at the tracked position: a shift of the head and a turn of every camera toward it
then differ only by perspective, and the cameras may aim a few tenths of a degree off; refinement
takes that out from the images, and a prior of a millimetre on the shift, which aimed them right,
scored 0.8 dB lower after refinement (docs/notebook/2026-11-26-camera-refinement.md). Then the
refinement's gauge (``rigid`` by default) is applied, so the result starts ``[cameras] refine``
exactly as an earlier round's cameras would. A union of sequences shifts each camera per sequence;
one turn per camera, about each pose's own centre, fits all its poses.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..camera import Camera
from ..data.capture import Capture
from ..data.landmarks import capture_landmarks
from ..errors import InputError
from ..flame.landmarks import EMBEDDING_FILES, STATIC_IBUG, LandmarkEmbedding, head_landmarks
from ..flame.lbs import axis_angle_to_matrix
from ..flame.model import FlameModel
from .camera_refine import CameraOffsets
from .config import CAMERA_GAUGES
from .data import FlameTable

HUBER_FRACTION = 0.01  # the Huber loss's knee, as a fraction of the image width (1.3 px at 128²)
# A round that lowers the loss by less than this fraction ends the solve (past the first round or
# two the cameras and heads only slide along the turn they share, a hundred-thousandth of a degree),
# and so does a loss this small (px²: landmarks met to a thousandth of a pixel).
ROUND_GAIN = 1e-4
FITTED_LOSS = 1e-6
MIN_LANDMARKS = 20  # weighted observations a camera needs to be turned


@dataclasses.dataclass
class LandmarkCameras:
    cameras: dict[str, Camera]  # every training camera, turned (or kept) and the gauge applied
    report: dict  # per camera: landmarks used, rotation (degrees), RMS before/after (pixels), why kept ('' if turned)


def training_cameras(capture: Capture, split: str = "train") -> dict[str, Camera]:
    """Each training camera as first met (see :func:`camera_poses`)."""
    return {cid: poses[0] for cid, poses in camera_poses(capture, split)[0].items()}


def camera_poses(capture: Capture, split: str = "train") -> tuple[dict[str, list[Camera]], dict[tuple[str, int], int]]:
    """Each training camera's poses (first met first) and which of them each ``(camera id,
    timestep)`` frame uses. A union of sequences shifts its cameras per sequence (VHAP moves every
    sequence by its mean head translation); one turn about each pose's own centre fits them all. A
    camera that turns or changes its intrinsics between frames is refused: no single turn fits it."""
    poses: dict[str, list[Camera]] = {}
    used: dict[tuple[str, int], int] = {}
    for frame in capture.frames(split):
        camera = capture.camera(frame)
        known = poses.setdefault(frame.camera_id, [camera])
        index = next((i for i, pose in enumerate(known) if np.allclose(pose.w2c, camera.w2c, atol=1e-9)), None)
        if index is None:
            same_turn = np.allclose(known[0].w2c[:3, :3], camera.w2c[:3, :3], atol=1e-9)
            if not (same_turn and np.allclose(known[0].K, camera.K)):
                raise InputError(capture.root, frame.camera_id, "the camera turns or changes its intrinsics between "
                                                                "frames; cameras from landmarks need fixed cameras")
            index = len(known)
            known.append(camera)
        used[frame.camera_id, frame.timestep_index] = index
    return poses, used


def solve_cameras(capture: Capture, head_file, embedding: LandmarkEmbedding | None = None, *,
                  points=STATIC_IBUG, gauge: str = CAMERA_GAUGES[0], split: str = "train") -> LandmarkCameras:
    """Turn the capture's ``split`` cameras to fit its landmark files (``landmark2d/``).
    ``embedding``: where the landmarks lie on ``head_file``'s mesh (when None: the procedural head's
    own, or a FLAME embedding file beside the model, :func:`head_landmarks`)."""
    poses, used = camera_poses(capture, split)
    cameras = {cid: known[0] for cid, known in poses.items()}
    timesteps = sorted({f.timestep_index for f in capture.frames(split)})
    table = FlameTable(timesteps, capture.flame_params_stacked(timesteps))
    model = FlameModel.load(head_file, n_vertices=table.n_vertices)
    model.check_counts(table.params(timesteps[0]), capture.flame_param_file(timesteps[0]))
    if embedding is None:
        embedding = head_landmarks(head_file, model.faces.numpy())
        if embedding is None:
            raise InputError(head_file, None, "no landmark embedding for this head model: pass FLAME's, or put it "
                                              f"beside the model as {' or '.join(EMBEDDING_FILES)}")
    found = capture_landmarks(capture, cameras)
    if not found:
        raise InputError(capture.root / "landmark2d", None, "no landmark file for any training camera "
                                                            "(expected landmark2d/STAR/<camera id>.npz, docs/data-format.md)")
    embedding = embedding.subset(np.asarray(points)).check(len(model.faces), "landmark embedding")
    ids = sorted(found)
    views = [(k, j) for k, cid in enumerate(ids) for j in range(len(poses[cid]))]  # (camera, pose) pairs
    observed = np.stack([found[ids[k]][timesteps][:, embedding.ibug] for k, _ in views])  # (V,T,L,3)
    observed[..., 2] *= np.array([[used.get((ids[k], t)) == j for t in timesteps] for k, j in views],
                                 np.float64)[..., None]
    with torch.no_grad():
        landmarks = embedding.positions(model(**table.params()).double(), model.faces)  # (T,L,3)
    problem = _Adjustment([poses[ids[k]][j] for k, j in views], [k for k, _ in views], landmarks,
                          torch.as_tensor(observed))
    enough = problem.count >= MIN_LANDMARKS
    # One camera's turn about its centre is a rigid motion of every timestep's head, which the
    # adjustment corrects anyway: with fewer than two cameras it would fit any turn.
    solved = int(enough.sum()) >= 2
    before = problem.rms_by_camera()
    if solved:
        problem.solve()
    after = problem.rms_by_camera()
    offsets = CameraOffsets(cameras, gauge)
    with torch.no_grad():
        for k, camera_id in enumerate(ids):
            offsets.rotation[offsets.index[camera_id]].copy_(problem.turn[k].float())
    offsets.fix_gauge()
    report = {cid: {"landmarks": int(problem.count[k]), "rms_before_px": before[k], "rms_after_px": after[k],
                    "kept": "" if solved and enough[k] else ("too few landmarks" if not enough[k] else
                                                             "the only camera with landmarks: its turn is the head's"),
                    "rotation_deg": float(np.degrees(offsets.rotation[offsets.index[cid]].detach().norm()))}
              for k, cid in enumerate(ids)}
    return LandmarkCameras(offsets.refined_cameras(), report)


class _Adjustment:
    """The least-squares problem: camera turns ``turn`` (C,3), each shared by the poses ``owner``
    gives it (a union's shifted cameras), mesh turns ``head_turn`` and shifts ``head_shift`` (T,3)
    about each timestep's landmark centroid."""

    def __init__(self, poses: list[Camera], owner: list[int], landmarks: torch.Tensor, observed: torch.Tensor):
        self.rotation = _stacked([c.w2c[:3, :3] for c in poses])
        self.centre = _stacked([c.center for c in poses])
        self.focal = _stacked([[c.fx, c.fy] for c in poses])
        self.principal = _stacked([[c.cx, c.cy] for c in poses])
        self.knee = HUBER_FRACTION * float(np.mean([c.width for c in poses]))
        self.owner = torch.as_tensor(owner)
        count = max(owner) + 1
        self.landmarks = landmarks
        self.centroid = landmarks.mean(1, keepdim=True)
        self.target = observed[..., :2]
        self.weight = observed[..., 2]
        self.count = torch.zeros(count, dtype=torch.float64).index_add_(0, self.owner, self.weight.sum((1, 2))).numpy()
        enough = torch.as_tensor(self.count >= MIN_LANDMARKS, dtype=torch.float64)[self.owner]
        self.weight = self.weight * enough[:, None, None]
        self.turn = torch.zeros(count, 3, dtype=torch.float64, requires_grad=True)
        self.head_turn = torch.zeros(len(landmarks), 3, dtype=torch.float64, requires_grad=True)
        self.head_shift = torch.zeros(len(landmarks), 3, dtype=torch.float64, requires_grad=True)

    def residual(self) -> torch.Tensor:
        """(C,T,L,2) pixel residuals."""
        head = axis_angle_to_matrix(self.head_turn)
        points = (self.landmarks - self.centroid) @ head.transpose(1, 2) + self.centroid + self.head_shift[:, None]
        # a camera turned by exp(ω) about its centre sees X as the calibrated one sees exp(−ω)(X − c) + c
        undo = axis_angle_to_matrix(-self.turn)[self.owner]
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
            before = self._loss_value()
            for _ in range(rounds):  # L-BFGS's 200 iterations a round, until a round barely lowers the loss
                optimiser.step(closure)
                after = self._loss_value()
                if after < FITTED_LOSS or before - after <= ROUND_GAIN * before:
                    break
                before = after
        finally:
            torch.set_num_threads(threads)

    @torch.no_grad()
    def _loss_value(self) -> float:
        return float(self.loss())

    @torch.no_grad()
    def rms_by_camera(self) -> list[float]:
        """RMS pixel residual of each camera (over all its poses)."""
        count = len(self.turn)
        squared = torch.zeros(count, dtype=torch.float64).index_add_(
            0, self.owner, ((self.residual() ** 2).sum(-1) * self.weight).sum((1, 2)))
        totals = torch.zeros(count, dtype=torch.float64).index_add_(0, self.owner, self.weight.sum((1, 2)))
        return [float(torch.sqrt(squared[k] / totals[k])) if totals[k] > 0 else float("nan") for k in range(count)]


def _stacked(rows) -> torch.Tensor:
    return torch.as_tensor(np.stack(rows), dtype=torch.float64)
