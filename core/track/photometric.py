"""The photometric stage of tracking: the skin, not the landmarks, decides where the head is.

A landmark detector's points are not fixed to the skin: they slide with the view by a few pixels
(docs/tracking.md), and a fit to landmarks alone follows them. A point of the skin looks the same in
neighbouring frames, so after the landmark fit the head is moved until each visible skin point
samples the same brightness in frame ``t`` as in frame ``t + gap`` (for a few gaps: a short one
for the motion, long ones for the parallax that tells the shape). No texture is estimated and no
lighting assumed: only frame-to-frame agreement. What a pair's differences share is removed: their
mean (exposure drift), and for a video a change linear in the skin's normal (a head turning under
still lights: one side of the face brightens as the other darkens), which the texture, sharp
where the normal is smooth, does not mimic.

What a point sees is decided once, from the landmark fit: facing the camera (its normal within
:data:`FACING` of the line of sight) and in front of every other point of the mesh near it on the
image (a coarse depth buffer of all vertices). The landmarks stay in the loss beside it.

Which frames are compared (:func:`frame_pairs`): a video's frames a few gaps apart, within each
clip (never across the cut between two); photos, which have no order in time, every two of them
(a still head seen from around it: the widest parallax there is). Photos of several sizes are
compared on one canvas, each at its own pixels. A video is fitted on every ``stride``-th frame
first, the frames between following, then on every frame (:mod:`.fit`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..camera import Camera
from ..flame.landmarks import LandmarkEmbedding
from ..flame.model import FlameModel

#: A point is seen when its normal is turned toward the camera by at least this cosine.
FACING = 0.35
#: The depth buffer's cells (pixels) and how far behind the nearest point a seen point may be (m).
DEPTH_CELL_PX, DEPTH_SLACK_M = 3, 0.006


#: The stage's settings unless given, chosen on validation clips and on validation photo folders
#: (docs/tracking.md): the skin has to outweigh the landmarks' lag to turn the head as far as it
#: turns, and a dozen photos take more iterations (which cost less than a clip's hundreds of
#: frames). A video's clip-long turn is found on every 4th frame first (a quarter of the cost an
#: iteration), then every frame is fitted: better and faster than every frame all along. A head
#: turning in front of a still phone turns under the room's lights: its shading's change is removed
#: (``shading``; photos of a still head, its light unchanged, were not tried with it).
CHOSEN = {"video": {"steps": 800, "weight": 30000.0, "stride": 4, "fine": 0.25, "shading": True},
          "photos": {"steps": 1920, "weight": 30000.0, "stride": 1, "fine": 0.0, "shading": False}}


@dataclasses.dataclass
class PhotometricSettings:
    steps: int | None = None  # L-BFGS iterations after the landmark fit (0: off; None: CHOSEN's)
    points: int = 1500  # skin points sampled
    gaps: tuple[int, ...] = (1, 5, 20, 60, 150)  # a video's frame pairs (t, t + gap); photos: every two
    stride: int | None = None  # a video's every stride-th frame is fitted, those between follow (None: CHOSEN's)
    fine: float | None = None  # after a stride > 1, this share of steps again on every frame (None: CHOSEN's)
    blur_px: float = 1.5  # the images' blur (a smooth basin for the sampling's gradient)
    weight: float | None = None  # of the mean robust brightness difference, beside the landmarks' pixels² (None: CHOSEN's)
    huber: float = 0.04  # the robust loss's knee (brightness, 0–1)
    shading: bool | None = None  # remove each pair's change linear in the skin's normal too (None: CHOSEN's)
    seed: int = 0

    def resolved(self, photos: bool) -> "PhotometricSettings":
        """These settings with what is not given taken from :data:`CHOSEN` for photos or a video
        (photos, which have no order in time, are all fitted: stride 1 whatever was given)."""
        chosen = CHOSEN["photos" if photos else "video"]
        given = {name: value for name, value in chosen.items() if getattr(self, name) is None}
        return dataclasses.replace(self, **{**given, **({"stride": 1} if photos else {})})

    def fine_steps(self) -> int:
        """The iterations on every frame after strided ones (of resolved settings)."""
        return 0 if self.stride == 1 else round(self.steps * self.fine)


def skin_points(model: FlameModel, count: int, seed: int) -> np.ndarray:
    """``count`` vertex ids drawn at random (seeded) from those the eyes do not carry (the eyeballs
    turn with the gaze under the lids: not skin)."""
    eyes = model.lbs_weights[:, 3:5].sum(1).numpy() > 0.5
    candidates = np.nonzero(~eyes)[0]
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(candidates, size=min(count, len(candidates)), replace=False))


def vertex_embedding(faces: np.ndarray, vertices: np.ndarray) -> LandmarkEmbedding:
    """Vertices as an embedding (a triangle holding each, weight 1 on it): posed by the same
    :class:`~.head.LandmarkHead` as the landmarks."""
    ids, first = np.unique(faces.ravel(), return_index=True)  # each vertex's first corner
    slot = first[np.searchsorted(ids, vertices)]
    barycentric = np.zeros((len(vertices), 3))
    barycentric[np.arange(len(vertices)), slot % 3] = 1.0
    return LandmarkEmbedding(slot // 3, barycentric, np.arange(len(vertices)))


def seen_points(model: FlameModel, params: dict, cameras: list[Camera], points: np.ndarray,
                chunk: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """``(T, P)`` whether each of ``points`` (vertex ids) is seen in each frame of ``params`` (a
    fit's, per frame arrays and one ``shape``) by that frame's camera of ``cameras`` (see the
    module's docstring), and ``(T, P, 3)`` their normals in the world."""
    frames = len(params["expr"])
    faces = model.faces.numpy()
    seen = np.zeros((frames, len(points)), bool)
    seen_normals = np.zeros((frames, len(points), 3))
    dtype = model.v_template.dtype
    for start in range(0, frames, chunk):
        given = {k: torch.as_tensor(params[k][start:start + chunk], dtype=dtype)
                 for k in ("expr", "rotation", "jaw_pose", "eyes_pose", "translation")}
        n = len(given["expr"])
        with torch.no_grad():
            vertices, _ = model.evaluate(shape=torch.as_tensor(params["shape"], dtype=dtype)[None].expand(n, -1), **given)
        vertices = vertices.double().numpy()
        normals = _vertex_normals(vertices, faces)
        seen_normals[start:start + n] = normals[:, points]
        for i in range(n):
            camera = cameras[start + i]
            cells_x = int(np.ceil(camera.width / DEPTH_CELL_PX)) + 1
            cells_y = int(np.ceil(camera.height / DEPTH_CELL_PX)) + 1
            pixels, depth = camera.project(vertices[i])
            ahead = depth > 1e-3
            cells = np.where(ahead[:, None], pixels, -1.0) // DEPTH_CELL_PX  # behind the camera: no cell
            cx = np.clip(cells[:, 0].astype(np.int64), 0, cells_x - 1)
            cy = np.clip(cells[:, 1].astype(np.int64), 0, cells_y - 1)
            nearest = np.full((cells_y, cells_x), np.inf)
            np.minimum.at(nearest, (cy[ahead], cx[ahead]), depth[ahead])
            sight = camera.center - vertices[i, points]
            facing = (seen_normals[start + i] * sight).sum(1) > FACING * np.linalg.norm(sight, axis=1)
            front = depth[points] <= nearest[cy[points], cx[points]] + DEPTH_SLACK_M
            seen[start + i] = facing & front & ahead[points]
    return seen, seen_normals


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals ``(T,V,3)`` (summed by torch's ``index_add_``: numpy's
    ``add.at`` took most of the visibility's time)."""
    a, b, c = (vertices[:, faces[:, k]] for k in range(3))
    face_normals = torch.as_tensor(np.cross(b - a, c - a))
    normals = torch.zeros(vertices.shape, dtype=face_normals.dtype)
    for k in range(3):
        normals.index_add_(1, torch.as_tensor(faces[:, k], dtype=torch.long), face_normals)
    normals = normals.numpy()
    return normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)


def frame_pairs(clips: np.ndarray, gaps: tuple[int, ...], photos: bool = False) -> np.ndarray:
    """``(N,2)`` the frames compared, earlier first: a video's ``(t, t + gap)`` within one clip
    (``clips (T,)``, each frame's), or every two photos."""
    frames = len(clips)
    if photos:
        return np.stack(np.triu_indices(frames, 1), 1).astype(np.int64)
    clips = np.asarray(clips)
    pairs = [np.stack([first, first + gap], 1) for gap in gaps if gap < frames
             for first in [np.nonzero(clips[:-gap] == clips[gap:])[0]]]
    return np.concatenate(pairs).astype(np.int64) if pairs else np.zeros((0, 2), np.int64)


class BrightnessAgreement:
    """The photometric loss: frames' brightness (``(T,H,W)``, or a list of ``(H,W)`` for photos of
    several sizes) blurred, the ``pairs (N,2)`` of frames compared (:func:`frame_pairs`), and which
    points each frame sees; called with the points' pixels ``(T,P,2)``.

    What each pair's differences share is removed first (least squares over the points both
    frames see): their mean (an exposure's drift), and with ``settings.shading`` and the points'
    ``normals (T,P,3)`` a change linear in the normal (a light that stays while the head turns
    under it brightens one side of the face and darkens the other). Sampled and compared in float32
    (the images' own precision), the sum returned in float64."""

    def __init__(self, brightness, seen: np.ndarray, settings: PhotometricSettings, pairs: np.ndarray,
                 normals: np.ndarray | None = None):
        canvas = _canvas(brightness)
        _, height, width = canvas.shape
        self.images = _blur(torch.as_tensor(canvas)[:, None], settings.blur_px)
        self.size = torch.tensor([width, height])
        pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
        points = seen.shape[1]
        # Only the (pair, point) entries both frames see are compared: each as its two frames'
        # samples in the (T·P) flattened ones, and its pair.
        pair, point = np.nonzero(seen[pairs[:, 0]] & seen[pairs[:, 1]])
        self.first = torch.as_tensor(pairs[pair, 0] * points + point)
        self.second = torch.as_tensor(pairs[pair, 1] * points + point)
        self.pair = torch.as_tensor(pair)
        self.count = max(len(pair), 1)
        self.huber = settings.huber
        # What is removed: each pair's least-squares fit of its differences on these features.
        features = np.ones((len(pair), 1))
        if settings.shading and normals is not None:
            features = np.concatenate([features, normals[pairs[pair, 0], point]], 1)
        features = torch.as_tensor(features)
        gram = torch.zeros(len(pairs), features.shape[1], features.shape[1], dtype=torch.float64)
        gram.index_add_(0, self.pair, features[:, :, None] * features[:, None, :])
        ridge = 1e-6 * torch.eye(features.shape[1], dtype=torch.float64)  # a pair with few points
        self.inverse_gram = torch.linalg.inv(gram + ridge).float()  # (N,F,F)
        self.features = features.float()

    def __call__(self, pixels: torch.Tensor) -> torch.Tensor:
        grid = (2 * pixels / self.size - 1).float()[:, :, None, :]  # (T,P,1,2), align_corners=False
        sampled = torch.nn.functional.grid_sample(self.images, grid, mode="bilinear", padding_mode="border",
                                                  align_corners=False)[:, 0, :, 0].reshape(-1)  # (T·P,)
        difference = sampled.index_select(0, self.second) - sampled.index_select(0, self.first)  # (K,) entries
        moments = torch.zeros(self.inverse_gram.shape[:2]).index_add(0, self.pair, self.features * difference[:, None])
        shared = (self.inverse_gram @ moments[..., None])[..., 0]  # each pair's fit (N,F)
        removed = (self.features * shared.index_select(0, self.pair)).sum(1)
        loss = torch.nn.functional.huber_loss(difference, removed, reduction="sum", delta=self.huber)
        return loss.double() / self.count


def _canvas(brightness) -> np.ndarray:
    """``(T,H,W)`` float32: frames of one size as they are; of several, each at the top left of the
    largest (its pixels keep their coordinates), on white (the captures' background)."""
    if isinstance(brightness, np.ndarray):
        return brightness.astype(np.float32, copy=False)
    height, width = (max(frame.shape[k] for frame in brightness) for k in (0, 1))
    canvas = np.ones((len(brightness), height, width), np.float32)
    for frame, image in zip(canvas, brightness):
        frame[:image.shape[0], :image.shape[1]] = image
    return canvas


def _blur(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur of ``(T,1,H,W)`` (separable, reflected at the edges: the frame keeps its size,
    unlike the SSIM window's valid-area blur in ``train/losses.py``), as a weighted sum of shifted
    copies: a one-channel convolution of a clip's frames took 3–4 times as long."""
    if sigma <= 0:
        return images
    radius = max(1, int(round(3 * sigma)))
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    kernel = torch.exp(-0.5 * (x / sigma) ** 2)
    kernel = (kernel / kernel.sum()).tolist()
    for dim, padding in ((3, (radius, radius, 0, 0)), (2, (0, 0, radius, radius))):
        padded = torch.nn.functional.pad(images, padding, mode="reflect")
        length = images.shape[dim]
        images = padded.narrow(dim, 0, length) * kernel[0]
        for shift, tap in enumerate(kernel[1:], 1):
            images.add_(padded.narrow(dim, shift, length), alpha=tap)
    return images


def brightness(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of sRGB values ``(…,3)``."""
    return rgb[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)
