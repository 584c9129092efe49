"""Faces in frames, offline: the face's box, 478 landmarks with irises, and the person's mask.

MediaPipe's models (:mod:`.models`) run on ``ai_edge_litert``'s TFLite interpreter with our own
pre- and post-processing (:mod:`.mediapipe_face`), which follows MediaPipe's graphs: on the
test photograph the 468 mesh points agree with MediaPipe's own pipeline to 0.01 px.

Per frame (:meth:`FaceTracker.__call__`):

1. the short-range detector finds every face (its count is reported; one face is followed);
2. the face mesh model (468 points) runs on a square region around the face, turned upright by
   the eye corners: the previous frame's landmarks' region while the face is tracked (MediaPipe's
   tracking), else the region of the largest detected face. When the mesh model's face presence
   falls below ``min_presence`` the face is detected again in the same frame;
3. the iris model refines each eye: points 468–472 (the eye on the image's left, the subject's
   right) and 473–477 are an iris centre, then its right, top, left and bottom edge points, in
   the order of MediaPipe's 478-point mesh;
4. the selfie segmentation model gives the person's mask.

Coordinates are pixels of the frame, as MediaPipe reports them (its normalised coordinates times
the frame's size); z is MediaPipe's relative depth (smaller is nearer the camera), scaled like x.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..errors import InputError
from . import mediapipe_face as mf
from .mediapipe_ibug68 import IBUG68_FROM_MESH

MESH_COUNT = 468
LANDMARK_COUNT = 478
IRIS_START = (468, 473)  # first point of each iris (its centre), eyes in EYE_CORNERS' order
# The iris model's points are centre, then edge points anticlockwise on screen from the eye's outer
# side; a mirrored (right) eye's come back mirrored: its edge points 1 and 3 swap.
_MIRRORED_IRIS = [0, 3, 2, 1, 4]


@dataclasses.dataclass(frozen=True)
class Face:
    """One face in a frame."""

    box: np.ndarray  # (4,) x1, y1, x2, y2 in pixels: the detector's box
    score: float  # the detector's score for the box (0: tracked, but not detected in this frame)
    presence: float  # the mesh model's face presence in [0, 1]
    landmarks: np.ndarray  # (478, 3) x, y in pixels, relative z (see the module's docstring)
    tracked: bool  # the region came from the previous frame's landmarks

    @property
    def confidence(self) -> np.ndarray:
        """(478,) a confidence per landmark: the face presence (the models give none per point)."""
        return np.full(LANDMARK_COUNT, self.presence)

    def ibug68(self) -> np.ndarray:
        """(68, 3): x, y of the 68 iBUG-300W points (:func:`ibug68`), and the confidence."""
        return np.concatenate([ibug68(self.landmarks), np.full((68, 1), self.presence)], 1)


@dataclasses.dataclass(frozen=True)
class FrameResult:
    """What :class:`FaceTracker` finds in one frame."""

    face: Face | None  # the followed face; None when none is found
    faces: int  # how many faces the detector found in the frame
    detections: np.ndarray  # (faces, 5): x1, y1, x2, y2, score of each, largest first
    mask: np.ndarray | None  # (H, W) float32 in [0, 1]: the person (None when not asked for)


def ibug68(landmarks: np.ndarray) -> np.ndarray:
    """The 68 iBUG-300W points ``(…, 68, 2)`` of MediaPipe mesh landmarks ``(…, 468 or 478, ≥2)``:
    each the mesh point :data:`.mediapipe_ibug68.IBUG68_FROM_MESH` names."""
    return np.asarray(landmarks)[..., IBUG68_FROM_MESH, :2]


class _Model:
    """One TFLite model: its interpreter, input size and output tensors."""

    def __init__(self, path, threads: int, role: str):
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError as error:
            raise ImportError("face tracking needs the ai-edge-litert package (Install Dependencies in Blender, "
                              "or `pip install -r requirements.txt`)") from error
        try:
            self.interpreter = Interpreter(model_path=os.fspath(path), num_threads=max(1, int(threads)))
            self.interpreter.allocate_tensors()
        except (ValueError, RuntimeError) as error:
            raise InputError(path, None, f"not a usable TFLite model for the face {role} ({error})") from None
        detail = self.interpreter.get_input_details()[0]
        self.input_index = detail["index"]
        self.height, self.width = int(detail["shape"][1]), int(detail["shape"][2])
        self.outputs = [d["index"] for d in self.interpreter.get_output_details()]

    def __call__(self, tensor: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, tensor[None].astype(np.float32, copy=False))
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(index) for index in self.outputs]


class FaceTracker:
    """Detects and follows one face through a sequence of frames (see the module's docstring).

    ``threads``: the interpreters' CPU threads. ``mask``: also segment the person. ``track``:
    take the next frame's region from this frame's landmarks (frames of one video); ``False`` for
    unrelated photos (each frame detected afresh; or call :meth:`reset` between sequences).
    ``models``: model files by role (default: the installed, verified ones, :func:`.models.find_all`).
    """

    def __init__(self, threads: int = 2, mask: bool = True, track: bool = True, min_detection: float = 0.5,
                 min_presence: float = 0.5, models: dict | None = None):
        if models is None:
            from .models import find_all

            models = find_all()
        self.detector = _Model(models["detector"], threads, "detector")
        self.mesh = _Model(models["landmarks"], threads, "landmarks")
        self.iris = _Model(models["iris"], threads, "iris")
        self.segmenter = _Model(models["segmentation"], threads, "segmentation") if mask else None
        self.track, self.min_detection, self.min_presence = track, min_detection, min_presence
        self._roi: mf.Roi | None = None

    def reset(self) -> None:
        """Forget the followed face: the next frame is detected afresh."""
        self._roi = None

    def __call__(self, frame: np.ndarray) -> FrameResult:
        boxes, keypoints, scores = self.detect(frame)
        face = None
        if self._roi is not None:
            face = self._face(frame, self._roi, tracked=True)
        if face is None and len(boxes):  # detect again: the largest face
            face = self._face(frame, mf.roi_from_box(boxes[0], keypoints[0, 0], keypoints[0, 1], mf.FACE_ROI_SCALE),
                              tracked=False)
        if face is not None:
            face = _with_box(face, boxes, scores)
        self._roi = (mf.roi_from_points(face.landmarks[:MESH_COUNT], *mf.FACE_ROTATION_POINTS, mf.FACE_ROI_SCALE)
                     if face is not None and self.track else None)
        detections = np.concatenate([boxes, scores[:, None]], 1) if len(boxes) else np.zeros((0, 5))
        mask = self.segment(frame) if self.segmenter is not None else None
        return FrameResult(face, len(boxes), detections, mask)

    def _face(self, frame: np.ndarray, roi: mf.Roi, tracked: bool) -> Face | None:
        mesh, presence = self.mesh_points(frame, roi)
        if presence < self.min_presence:
            return None
        landmarks = np.concatenate([mesh, self.irises(frame, mesh)]).astype(np.float32)
        return Face(np.zeros(4), 0.0, presence, landmarks, tracked)

    # -- the stages (public for benchmarks and tests) ----------------------------------------------
    def detect(self, frame: np.ndarray):
        """Every face of the frame: boxes ``(N,4)``, keypoints ``(N,6,2)``, scores, largest first."""
        image, scale = _as_rgb(frame)
        view = mf.letterbox(image.shape[1], image.shape[0])
        tensor = mf.resample(image, view, self.detector.width, self.detector.height, border="zero")
        tensor = tensor * np.float32(2.0 * scale) - np.float32(1.0)
        regressors, logits = self.detector(tensor)
        boxes, keypoints, scores = mf.decode_detections(regressors[0], logits[0, :, 0], view, self.min_detection)
        order = np.argsort(-np.prod(boxes[:, 2:] - boxes[:, :2], axis=1), kind="stable") if len(boxes) else []
        return boxes[order], keypoints[order], scores[order]

    def mesh_points(self, frame: np.ndarray, roi: mf.Roi) -> tuple[np.ndarray, float]:
        """The 468 mesh points ``(468, 3)`` of the face in ``roi``, and the face presence."""
        image, scale = _as_rgb(frame)
        tensor = mf.resample(image, roi, self.mesh.width, self.mesh.height) * np.float32(scale)
        points, presence = self.mesh(tensor)
        return mf.project_points(points.reshape(MESH_COUNT, 3), roi, self.mesh.width), mf.sigmoid(presence.ravel()[0])

    def irises(self, frame: np.ndarray, mesh: np.ndarray) -> np.ndarray:
        """The ten iris points ``(10, 3)`` of a face's mesh points (both eyes, see the module's docstring);
        the model knows left eyes only, so the other eye is mirrored."""
        image, scale = _as_rgb(frame)
        found = []
        for index, roi in enumerate(mf.eye_rois(mesh)):
            mirrored = index == 1
            tensor = mf.resample(image, roi, self.iris.width, self.iris.height, flip=mirrored) * np.float32(scale)
            _, iris = self.iris(tensor)
            points = mf.project_points(iris.reshape(5, 3), roi, self.iris.width, flip=mirrored)
            found.append(points[_MIRRORED_IRIS] if mirrored else points)
        return np.concatenate(found)

    def segment(self, frame: np.ndarray) -> np.ndarray:
        """The person's mask ``(H, W)`` in [0, 1]: the model sees the whole frame, stretched."""
        if self.segmenter is None:
            raise ValueError("this FaceTracker was made with mask=False")
        image, scale = _as_rgb(frame)
        height, width = image.shape[:2]
        whole = mf.Roi(width / 2.0, height / 2.0, float(width), float(height))
        tensor = mf.resample(image, whole, self.segmenter.width, self.segmenter.height) * np.float32(scale)
        (plane,) = self.segmenter(tensor)
        mask = mf.resize_plane(plane[0, :, :, 0], height, width)
        return np.clip(mask, 0.0, 1.0, out=mask)


def _as_rgb(frame) -> tuple[np.ndarray, float]:
    """The frame as (H, W, 3) and the factor that brings its values to [0, 1]."""
    image = np.asarray(frame)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or min(image.shape[:2]) < 2:
        raise InputError(None, "frame", f"expected an (H, W, 3) RGB image, found shape {image.shape}")
    image = image[..., :3]
    if image.dtype == np.uint8:
        return image, 1.0 / 255.0
    if not np.issubdtype(image.dtype, np.floating):
        raise InputError(None, "frame", f"expected uint8 or float values in [0, 1], found {image.dtype}")
    return image, 1.0


def _with_box(face: Face, boxes: np.ndarray, scores: np.ndarray) -> Face:
    """The face with the detector's box of it: the best-scored detection whose centre lies within the
    mesh's bounds; the mesh's bounds and score 0 when the detector missed the face in this frame."""
    mesh = face.landmarks[:MESH_COUNT, :2]
    low, high = mesh.min(0), mesh.max(0)
    if len(boxes):
        centres = 0.5 * (boxes[:, :2] + boxes[:, 2:])
        inside = np.where(np.all((centres >= low) & (centres <= high), axis=1))[0]
        if len(inside):
            best = inside[np.argmax(scores[inside])]
            return dataclasses.replace(face, box=boxes[best].astype(np.float64), score=float(scores[best]))
    return dataclasses.replace(face, box=np.concatenate([low, high]).astype(np.float64), score=0.0)


# -- the overlay ---------------------------------------------------------------------------------
COLOURS = {"mesh": (80, 230, 80), "iris": (255, 60, 60), "ibug": (60, 140, 255), "box": (255, 220, 0),
           "mask": (0, 230, 255)}


def draw_overlay(frame: np.ndarray, result: FrameResult, crop=None, zoom: int = 1) -> np.ndarray:
    """The frame (H, W, 3 uint8) with what was found: the person's outside dimmed and its outline,
    the detector's box, the mesh (green), the irises (red, with their circles) and the iBUG-68
    points (blue). ``crop`` (x1, y1, x2, y2 pixels) and ``zoom`` (an integer) show a part enlarged."""
    from PIL import Image, ImageDraw

    from ..io.image import to_uint8

    image = np.asarray(frame)
    image = image[..., :3] if image.dtype == np.uint8 else to_uint8(image[..., :3])
    x0, y0 = 0, 0
    mask = result.mask
    if crop is not None:
        x0, y0, x1, y1 = (int(round(v)) for v in crop)
        image = image[y0:y1, x0:x1]
        mask = mask[y0:y1, x0:x1] if mask is not None else None
    image = np.repeat(np.repeat(image, zoom, 0), zoom, 1)
    if mask is not None:
        mask = np.repeat(np.repeat(mask, zoom, 0), zoom, 1) > 0.5
        image = np.where(mask[..., None], image, (image * 0.45).astype(np.uint8))
        inside = mask.copy()  # the mask's pixels whose four neighbours are all in it (the frame's edge counts as in)
        inside[1:] &= mask[:-1]
        inside[:-1] &= mask[1:]
        inside[:, 1:] &= mask[:, :-1]
        inside[:, :-1] &= mask[:, 1:]
        edge = mask & ~inside
        edge[1:] |= edge[:-1].copy()  # two pixels wide
        edge[:, 1:] |= edge[:, :-1].copy()
        image = np.where(edge[..., None], np.array(COLOURS["mask"], np.uint8), image)
    canvas = Image.fromarray(np.ascontiguousarray(image))
    draw = ImageDraw.Draw(canvas)

    def at(points):
        return (np.asarray(points, np.float64)[..., :2] - (x0, y0)) * zoom

    def dots(points, colour, radius):
        for x, y in at(points):
            draw.ellipse((x - radius, y - radius, x + radius, y + radius), fill=colour)

    face = result.face
    if face is not None:
        (bx1, by1), (bx2, by2) = at(face.box.reshape(2, 2))
        draw.rectangle((bx1, by1, bx2, by2), outline=COLOURS["box"], width=max(1, zoom))
        dots(face.landmarks[:MESH_COUNT], COLOURS["mesh"], 0.5 + 0.4 * zoom)
        for start in IRIS_START:
            iris = at(face.landmarks[start:start + 5])
            radius = float(np.mean(np.linalg.norm(iris[1:] - iris[0], axis=1)))
            cx, cy = iris[0]
            draw.ellipse((cx - radius, cy - radius, cx + radius, cy + radius), outline=COLOURS["iris"],
                         width=max(1, zoom // 2))
        dots(face.landmarks[MESH_COUNT:], COLOURS["iris"], 0.6 + 0.5 * zoom)
        dots(ibug68(face.landmarks), COLOURS["ibug"], 0.8 + 0.7 * zoom)
    return np.asarray(canvas)


def write_overlay(path, frame: np.ndarray, result: FrameResult, crop=None, zoom: int = 1) -> None:
    """:func:`draw_overlay` written as a PNG (atomically)."""
    from ..io.image import write_png

    write_png(path, draw_overlay(frame, result, crop, zoom))
