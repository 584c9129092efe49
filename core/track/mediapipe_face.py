"""The pre- and post-processing around MediaPipe's face models, in numpy: what MediaPipe's own
graphs (face detection short range, face landmarks, iris landmarks, selfie segmentation) do
around each ``.tflite`` file, so the models can run on a bare TFLite interpreter.

Coordinates are image pixels, continuous: pixel ``(i, j)`` covers ``[j, j+1) × [i, i+1)``, so its
centre is at ``(j + 0.5, i + 0.5)`` and the models' normalised coordinates are these divided by
the image size. A region of interest (:class:`Roi`) is a rotated rectangle in these pixels; a
model's input is the region resampled to the model's size (bilinear, edges replicated, no
anti-aliasing: as MediaPipe's CPU path), and the model's output points are mapped back by the
same transform.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

# -- face detection (BlazeFace, short range: 128 × 128, 896 anchors) ----------------------------
DETECTOR_SIZE = 128
DETECTOR_STRIDES = (8, 16, 16, 16)  # SSD layers; layers of one stride share a grid
DETECTOR_KEYPOINTS = 6  # right eye, left eye, nose tip, mouth, right ear tragion, left ear tragion
SCORE_CLIP = 100.0
MIN_DETECTION_SCORE = 0.5
NMS_IOU = 0.3

# -- regions -------------------------------------------------------------------------------------
FACE_ROI_SCALE = 1.5  # a face's region: its box (detector) or its landmarks' bounds, × 1.5, square
EYE_ROI_SCALE = 2.3  # an eye's region: its two corners' bounds × 2.3, square
LANDMARK_SIZE = 192
IRIS_SIZE = 64
SEGMENTATION_SIZE = 256

# mesh points that orient the regions: the outer eye corners (face), each eye's two corners
FACE_ROTATION_POINTS = (33, 263)
EYE_CORNERS = ((33, 133), (362, 263))  # the eye on the image's left (subject's right), then the other


@dataclasses.dataclass(frozen=True)
class Roi:
    """A rotated rectangle in image pixels: centre, size, and angle (radians, clockwise on screen:
    the image's y axis points down) from the image's axes to the rectangle's."""

    cx: float
    cy: float
    width: float
    height: float
    angle: float = 0.0

    def to_image(self, uv: np.ndarray) -> np.ndarray:
        """Points ``(…,2)`` in the rectangle's unit square ([0,1]², x along its width) → image pixels."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        x = (uv[..., 0] - 0.5) * self.width
        y = (uv[..., 1] - 0.5) * self.height
        return np.stack([c * x - s * y + self.cx, s * x + c * y + self.cy], -1)

    def corners(self) -> np.ndarray:
        return self.to_image(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))


def _normalized_angle(angle: float) -> float:
    return angle - 2 * math.pi * math.floor((angle + math.pi) / (2 * math.pi))


def roi_from_box(box, start, end, scale: float) -> Roi:
    """MediaPipe's rect from a box and two points: the box's centre, turned so that ``start → end``
    lies along +x, its longer side × ``scale`` as a square (``DetectionsToRects`` then
    ``RectTransformation`` with ``square_long``)."""
    x1, y1, x2, y2 = (float(v) for v in box)
    angle = _normalized_angle(-math.atan2(-(float(end[1]) - float(start[1])), float(end[0]) - float(start[0])))
    side = max(x2 - x1, y2 - y1) * scale
    return Roi(0.5 * (x1 + x2), 0.5 * (y1 + y2), side, side, angle)


def roi_from_points(points: np.ndarray, start: int, end: int, scale: float) -> Roi:
    """The region of a point set: its bounds, oriented by two of its points (see :func:`roi_from_box`)."""
    xy = np.asarray(points)[:, :2]
    box = (*xy.min(0), *xy.max(0))
    return roi_from_box(box, xy[start], xy[end], scale)


# -- resampling ----------------------------------------------------------------------------------

def resample(image: np.ndarray, roi: Roi, width: int, height: int, flip: bool = False,
             border: str = "replicate") -> np.ndarray:
    """The region ``roi`` of ``image`` (H,W,C) resampled to ``height × width`` float32 values of the
    image's range (bilinear). ``border``: what samples outside the image see, its nearest edge pixel
    (``"replicate"``) or zero (``"zero"``: the detector's letterbox). ``flip``: mirrored left-right
    (the iris model sees every eye as a left one).

    The sampling grid is MediaPipe's (OpenCV's ``warpPerspective`` from the region's corners to the
    output's corners, both taken as pixel indices): output pixel ``j`` samples the region at
    ``j / width``. The models were trained on inputs made so; sampling at pixel centres instead
    (``(j + 0.5) / width``) moves the detector's box by up to 3 % of its size on the test photograph."""
    u = np.arange(width, dtype=np.float32) / np.float32(width)
    if flip:
        u = u[::-1]
    v = np.arange(height, dtype=np.float32) / np.float32(height)
    x = (u - np.float32(0.5)) * np.float32(roi.width)
    y = (v - np.float32(0.5)) * np.float32(roi.height)
    if roi.angle == 0.0:  # separable: one coordinate per column, one per row
        px, py = (x + np.float32(roi.cx))[None, :], (y + np.float32(roi.cy))[:, None]
    else:
        c, s = np.float32(math.cos(roi.angle)), np.float32(math.sin(roi.angle))
        px = c * x[None, :] - s * y[:, None] + np.float32(roi.cx)
        py = s * x[None, :] + c * y[:, None] + np.float32(roi.cy)
    return _bilinear(image, px, py, border)


def _axis(position: np.ndarray, size: int, border: str):
    """Bilinear taps along one axis: the two indices and their weights (zero outside for ``"zero"``)."""
    if border == "replicate":
        position = np.clip(position, 0.0, size - 1.0)
    low = np.floor(position)
    fraction = (position - low).astype(np.float32)
    i0 = low.astype(np.int32)
    i1 = i0 + 1
    w0, w1 = 1.0 - fraction, fraction
    if border == "zero":
        w0 = w0 * ((i0 >= 0) & (i0 < size))
        w1 = w1 * ((i1 >= 0) & (i1 < size))
    elif border != "replicate":
        raise ValueError(f"border must be 'replicate' or 'zero', not {border!r}")
    return np.clip(i0, 0, size - 1), np.clip(i1, 0, size - 1), w0, w1


def _bilinear(image: np.ndarray, px: np.ndarray, py: np.ndarray, border: str) -> np.ndarray:
    h, w = image.shape[:2]
    x0, x1, wx0, wx1 = _axis(px, w, border)
    y0, y1, wy0, wy1 = _axis(py, h, border)
    flat = image.reshape(h * w, -1)
    row0, row1 = y0 * w, y1 * w

    def tap(index, weight):  # np.take and weights repeated per channel: several times faster than
        # fancy indexing and broadcasting over a length-3 axis, and the same values
        return np.take(flat, index, axis=0) * np.repeat(weight[..., None], flat.shape[1], -1)

    out = tap(row0 + x0, wy0 * wx0)
    out += tap(row0 + x1, wy0 * wx1)
    out += tap(row1 + x0, wy1 * wx0)
    out += tap(row1 + x1, wy1 * wx1)
    return out.astype(np.float32, copy=False)


def resize_plane(plane: np.ndarray, height: int, width: int) -> np.ndarray:
    """A 2D array resized to ``height × width`` float32 (bilinear, half-pixel centres, edges
    replicated: OpenCV's ``resize``): a model's mask brought to the frame's size."""
    ph, pw = plane.shape
    ys = np.clip((np.arange(height, dtype=np.float32) + 0.5) * np.float32(ph / height) - 0.5, 0.0, ph - 1.0)
    xs = np.clip((np.arange(width, dtype=np.float32) + 0.5) * np.float32(pw / width) - 0.5, 0.0, pw - 1.0)
    y0 = np.minimum(ys.astype(np.int32), max(ph - 2, 0))
    x0 = np.minimum(xs.astype(np.int32), max(pw - 2, 0))
    fy = (ys - y0).astype(np.float32)[:, None]
    fx = (xs - x0).astype(np.float32)
    y1, x1 = np.minimum(y0 + 1, ph - 1), np.minimum(x0 + 1, pw - 1)
    plane = plane.astype(np.float32, copy=False)
    rows = plane[y0] + (plane[y1] - plane[y0]) * fy  # (height, pw)
    out = np.take(rows, x1, axis=1)
    left = np.take(rows, x0, axis=1)
    out -= left
    out *= fx
    out += left
    return out


# -- the detector ---------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def detector_anchors() -> np.ndarray:
    """The 896 anchor centres (normalised) of the short-range detector: SSD anchors with a fixed
    size, two per cell and layer, layers of one stride sharing their grid."""
    centres = []
    layer = 0
    while layer < len(DETECTOR_STRIDES):
        stride = DETECTOR_STRIDES[layer]
        per_cell = 0
        while layer < len(DETECTOR_STRIDES) and DETECTOR_STRIDES[layer] == stride:
            per_cell += 2  # aspect ratio 1, plus the interpolated scale
            layer += 1
        cells = DETECTOR_SIZE // stride
        grid = (np.arange(cells) + 0.5) / cells
        yy, xx = np.meshgrid(grid, grid, indexing="ij")
        centres.append(np.repeat(np.stack([xx.ravel(), yy.ravel()], -1), per_cell, axis=0))
    return np.concatenate(centres).astype(np.float64)


def letterbox(image_width: int, image_height: int) -> Roi:
    """The detector's view of a whole frame: a square around it, the frame centred (padding on the
    shorter side), as MediaPipe's ``keep_aspect_ratio`` input."""
    side = float(max(image_width, image_height))
    return Roi(image_width / 2.0, image_height / 2.0, side, side, 0.0)


def decode_detections(regressors: np.ndarray, logits: np.ndarray, view: Roi,
                      min_score: float = MIN_DETECTION_SCORE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detector's raw output ``(896,16)``, ``(896,)`` → boxes ``(N,4)`` (x1, y1, x2, y2) and
    keypoints ``(N,6,2)`` in image pixels, and scores ``(N,)``: anchors above ``min_score``, merged by
    weighted non-maximum suppression, best first. ``view``: the frame's region the input showed."""
    scores = 1.0 / (1.0 + np.exp(-np.clip(logits.astype(np.float64), -SCORE_CLIP, SCORE_CLIP)))
    keep = np.where(scores >= min_score)[0]
    if len(keep) == 0:
        return np.zeros((0, 4)), np.zeros((0, DETECTOR_KEYPOINTS, 2)), np.zeros(0)
    raw = regressors[keep].astype(np.float64) / DETECTOR_SIZE
    anchors = detector_anchors()[keep]
    centre = raw[:, 0:2] + anchors
    half = 0.5 * raw[:, 2:4]
    points = np.concatenate([centre - half, centre + half,
                             raw[:, 4:4 + 2 * DETECTOR_KEYPOINTS] + np.tile(anchors, DETECTOR_KEYPOINTS)], 1)
    points = view.to_image(points.reshape(len(keep), -1, 2)).reshape(len(keep), -1)  # two box corners, keypoints
    boxes, keypoints, scores = _weighted_nms(points[:, :4], points[:, 4:], scores[keep])
    return boxes, keypoints.reshape(-1, DETECTOR_KEYPOINTS, 2), scores


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    area = lambda b: np.prod(np.clip(b[..., 2:] - b[..., :2], 0.0, None), axis=-1)  # noqa: E731
    union = area(box) + area(boxes) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def _weighted_nms(boxes, keypoints, scores, threshold: float = NMS_IOU):
    """MediaPipe's weighted suppression: the best remaining detection takes every other with an IoU
    above ``threshold``; its box and keypoints become their score-weighted mean, its score stays."""
    order = np.argsort(-scores, kind="stable")
    boxes, keypoints, scores = boxes[order], keypoints[order], scores[order]
    remaining = np.ones(len(scores), bool)
    out_boxes, out_points, out_scores = [], [], []
    for i in range(len(scores)):
        if not remaining[i]:
            continue
        overlap = remaining & (_iou(boxes[i], boxes) > threshold)
        overlap[i] = True
        weights = scores[overlap][:, None]
        out_boxes.append((boxes[overlap] * weights).sum(0) / weights.sum())
        out_points.append((keypoints[overlap] * weights).sum(0) / weights.sum())
        out_scores.append(scores[i])
        remaining &= ~overlap
    return np.array(out_boxes), np.array(out_points), np.array(out_scores)


# -- landmarks and irises ------------------------------------------------------------------------

def project_points(points: np.ndarray, roi: Roi, size: int, flip: bool = False) -> np.ndarray:
    """A model's points ``(N,3)`` in its ``size × size`` input → image pixels ``(N,3)``: x, y, and z
    scaled like x (MediaPipe's relative depth, in pixels)."""
    uv = points[:, :2] / size
    if flip:
        uv = np.stack([1.0 - uv[:, 0], uv[:, 1]], -1)
    xy = roi.to_image(uv)
    return np.concatenate([xy, (points[:, 2:3] / size) * roi.width], 1)


def eye_rois(landmarks: np.ndarray) -> list[Roi]:
    """The two eyes' regions for the iris model, from the face mesh's eye corners (:data:`EYE_CORNERS`)."""
    rois = []
    for start, end in EYE_CORNERS:
        xy = landmarks[[start, end], :2]
        rois.append(roi_from_box((*xy.min(0), *xy.max(0)), xy[0], xy[1], EYE_ROI_SCALE))
    return rois


def sigmoid(value) -> float:
    return float(1.0 / (1.0 + math.exp(-float(np.clip(value, -SCORE_CLIP, SCORE_CLIP)))))
