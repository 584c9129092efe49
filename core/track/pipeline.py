"""Footage in, capture out: read the frames, find the face in each, fit the head model, write the capture.

The capture is an ordinary one in the GaussianAvatars/VHAP layout (:mod:`..data.writer`), so
``check-capture``, ``train``, ``eval``, ``solve-cameras`` and Blender's Import Capture take it as
they take any other: the frames as images on white (through the person's mask, as VHAP exports
them), the person's mask as each frame's foreground mask, one fixed camera for a video (``cam00``,
the fitted focal length; several videos: a camera each, ``cam00``, ``cam01``, …, their frames one
after another; a photo folder: a camera per photo, one lens), FLAME parameters per frame (the
head's rotation and translation carry the motion between camera and head; one shape), the 68 iBUG
points in ``landmark2d/``, and the head model file. ``tracking.json`` says how each frame went.

Frames where no face was found keep their timestep: their parameters are interpolated by the fit
(its smoothness term; they have no landmarks) and they are left out of every split, so nothing
trains or is scored on a guess; ``tracking.json`` lists them. The last tenth of the frames (of
each clip) is the ``test`` split (frames the avatar never trains on, for self-reenactment), the
rest ``train``.

Interrupted (Ctrl-C), the folder has no split files and no reader takes it; the detections done
so far are kept in ``track_detections.npz``, and the same command resumes from there.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import time

import numpy as np

from ..data import layout
from ..data.writer import CaptureWriter
from ..errors import InputError
from ..io.atomic import check_output_target, write_json
from ..io.npz import load_npz, save_npz
from .fit import FitSettings

DETECTIONS_FILE = "track_detections.npz"
REPORT_FILE = "tracking.json"
TEST_FRACTION = 0.1
#: Detections are saved for a resume every this many frames.
SAVE_EVERY = 25


@dataclasses.dataclass
class TrackSettings:
    size: int | None = 512  # the capture's longer side (frames are shrunk to it; None: as stored)
    focal_px: float | None = None  # at the input's (first frame's) size; None: the file's metadata, else estimated
    threads: int = 2
    fit: FitSettings = dataclasses.field(default_factory=FitSettings)  # its focal: see focal_px
    head_file: str | os.PathLike | None = None  # None: the procedural head of subject 0


@dataclasses.dataclass
class Detections:
    """What the detector found, frame by frame (``T`` frames): 478 landmarks, presence (0: no face)."""

    landmarks: np.ndarray  # (T, 478, 3) pixels of the capture's images
    presence: np.ndarray  # (T,)
    faces: np.ndarray  # (T,) faces the detector found
    times: np.ndarray  # (T,) seconds (NaN for photos)
    indices: np.ndarray  # (T,) the input's frame numbers
    sizes: np.ndarray  # (T,2) width and height of each frame in the capture
    clips: np.ndarray  # (T,) the video each frame is from (several videos; otherwise 0)

    @classmethod
    def empty(cls) -> "Detections":
        return cls(np.zeros((0, 478, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int32),
                   np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 2), np.int64), np.zeros(0, np.int64))

    def append(self, landmarks, presence, faces, time_s, index, size, clip: int = 0) -> None:
        self.landmarks = np.concatenate([self.landmarks, np.asarray(landmarks, np.float32)[None]])
        self.presence = np.append(self.presence, np.float32(presence))
        self.faces = np.append(self.faces, np.int32(faces))
        self.times = np.append(self.times, np.nan if time_s is None else time_s)
        self.indices = np.append(self.indices, index)
        self.sizes = np.concatenate([self.sizes, np.asarray(size, np.int64)[None]])
        self.clips = np.append(self.clips, np.int64(clip))

    @property
    def one_size(self) -> bool:
        return len(self.sizes) == 0 or bool((self.sizes == self.sizes[0]).all())

    def save(self, path: pathlib.Path, source: str) -> None:
        save_npz(path, {**dataclasses.asdict(self), "source": np.array(source)})

    @classmethod
    def read(cls, path: pathlib.Path) -> tuple["Detections", str]:
        """Saved detections and the key of the input they were found in."""
        data = load_npz(path)
        fields = {field.name: data[field.name] for field in dataclasses.fields(cls) if field.name in data}
        fields.setdefault("clips", np.zeros(len(fields["presence"]), np.int64))  # saved before several videos were read
        return cls(**fields), str(data.get("source", ""))

    @classmethod
    def load(cls, path: pathlib.Path, source: str) -> "Detections | None":
        """The saved detections of the same input, or None (another input's are not resumed)."""
        if not path.is_file():
            return None
        detections, saved_from = cls.read(path)
        return detections if saved_from == source else None


def check_output_folder(out: pathlib.Path, source: str) -> bool:
    """The output is new, empty, or an interrupted track of the same input (True: resume)."""
    check_output_target(out, folder=True)  # a file, FIFO or device where the folder would be
    if not out.exists() or not any(out.iterdir()):
        return False
    if Detections.load(out / DETECTIONS_FILE, source) is not None and not (out / "transforms_train.json").exists():
        return True
    raise InputError(out, None, "is not empty; expected a new or empty folder (or an interrupted track of the "
                                "same input, to resume)")


def track_footage(source, out, settings: TrackSettings = TrackSettings(), selection=None, progress=None,
                  keep_detections: bool = False) -> dict:
    """Track ``source`` (a video, a photo folder or a list of photos) into the capture folder ``out``.

    ``progress(stage, done, total)`` is called as it goes (stages: "detect", "fit", "write").
    Returns the report written to ``tracking.json``. ``keep_detections``: leave
    ``track_detections.npz`` for :func:`refit` (choosing the fit's settings).
    """
    from ..flame.model import FlameModel
    from .decode import open_footage
    from .inputs import FrameSelection

    out = pathlib.Path(out)
    footage = open_footage(source)
    info = footage.info
    settings.fit.check(info.kind == "photos")  # before minutes of finding the face
    paths = [clip.path for clip in info.clips] if info.clips else [info.path]
    key = f"{'|'.join(str(pathlib.Path(path).resolve()) for path in paths)}|{selection or FrameSelection()}|{settings.size}"
    resume = check_output_folder(out, key)
    out.mkdir(parents=True, exist_ok=True)
    head_file = _head_model(out, settings.head_file)
    model = FlameModel.load(head_file)

    started = time.monotonic()
    detections = _detect(footage, out, key, settings, selection or FrameSelection(), resume, progress)
    detect_s = time.monotonic() - started
    if not (detections.presence > 0).any():
        raise InputError(info.path, None, "no face was found in any frame")

    report = _fit_and_write(out, model, head_file, detections, settings, info, progress)
    report["seconds"]["detect"] = round(detect_s, 2)
    report["detect_ms_per_frame"] = round(1000 * detect_s / max(len(detections.presence), 1), 1)
    write_json(out / REPORT_FILE, report)
    if not keep_detections:
        (out / DETECTIONS_FILE).unlink(missing_ok=True)
    return report


def refit(out, settings: TrackSettings) -> dict:
    """Fit a tracked folder's kept detections again with other settings (the same footage, the same
    frames); rewrites its parameters, split files and ``tracking.json``."""
    from ..flame.model import FlameModel
    from ..io.jsonfile import read_json_object
    from .decode import open_footage

    out = pathlib.Path(out)
    previous = read_json_object(out / REPORT_FILE)
    detections, _ = Detections.read(out / DETECTIONS_FILE)
    head_file = out / previous["head_model"]
    info = open_footage(previous["source"]).info
    report = _fit_and_write(out, FlameModel.load(head_file), head_file, detections, settings, info, None)
    report["seconds"]["detect"] = previous["seconds"]["detect"]
    report["detect_ms_per_frame"] = previous["detect_ms_per_frame"]
    write_json(out / REPORT_FILE, report)
    return report


def _fit_and_write(out, model, head_file, detections, settings, info, progress) -> dict:
    started = time.monotonic()
    fit = _fit(out, model, detections, settings, info, progress)
    fit_s = time.monotonic() - started
    report = _write_capture(out, fit, detections, head_file, model, info.kind != "photos", progress)
    photometric = settings.fit.photometric.resolved(info.kind == "photos")
    report.update(source=str(info.path), kind=info.kind, input_size=[info.width, info.height], fps=info.fps,
                  seconds={"fit": round(fit_s, 2)}, fit_steps=settings.fit.steps, photometric_steps=photometric.steps,
                  photometric_stride=photometric.stride, photometric_fine_steps=photometric.fine_steps(),
                  photometric_shading=photometric.shading)
    if info.clips:  # several videos: each one's; the fields above are the first's
        report.update(source=[str(clip.path) for clip in info.clips], clips=[
            {"source": str(clip.path), "camera": _camera_id(number), "frames": int((detections.clips == number).sum()),
             "input_size": [clip.width, clip.height], "fps": clip.fps,
             "focal_px": round(float(fit.cameras[number].fx), 2)} for number, clip in enumerate(info.clips)])
    return report


def _camera_id(clip: int) -> str:
    """A video's camera: ``cam00`` for the first (the only one, for one clip), ``cam01``, … ."""
    return f"cam{clip:02d}"


def _camera_number(clip: int, t: int, photos: bool) -> int:
    """The camera whose folder frame ``t`` is written in: its clip's, or for photos its own (a
    photo is its own camera)."""
    return t if photos else clip


def _head_model(out: pathlib.Path, head_file) -> pathlib.Path:
    from ..data.generator import write_head_model

    existing = [out / name for name in ("head.pkl", "head.npz") if (out / name).is_file()]
    return existing[0] if existing else write_head_model(out, 0, 0, head_file)


def _detect(footage, out, key, settings, selection, resume, progress):
    """Detect every selected frame at the input's own size (the face models see the most detail
    there), and write its image and mask at the capture's size as it goes (in a thread:
    :mod:`.frame_writer`); resumable: detections are saved only once their frames are written."""
    from .detect import FaceTracker
    from .frame_writer import FrameWriter
    from .inputs import output_size

    detections = Detections.load(out / DETECTIONS_FILE, key) if resume else None
    detections = detections or Detections.empty()
    done = len(detections.presence)
    video = footage.info.kind != "photos"
    total = footage.info.frame_count
    position = 0
    with FrameWriter(out) as writer:
        for clip, part in enumerate(getattr(footage, "videos", [footage])):  # several videos: one after another
            tracker = FaceTracker(threads=settings.threads, track=video)  # each clip's own: no tracking across the cut
            first = None
            for frame in part.frames(selection):
                height, width = frame.rgb.shape[:2]
                size = output_size(width, height, min(settings.size, max(width, height)) if settings.size else None)
                if first is None:
                    first = (width, height)
                elif video and (width, height) != first:
                    raise InputError(part.info.path, "size", f"frame {frame.index} is {width}x{height}, the first "
                                                              f"{first[0]}x{first[1]}: one camera needs one size")
                timestep, position = position, position + 1
                if timestep < done:
                    continue  # a resumed track: already detected and written
                _detect_frame(tracker, frame, size, detections, writer, timestep,
                              _camera_number(clip, timestep, not video), clip)
                if len(detections.presence) % SAVE_EVERY == 0:
                    writer.flush()
                    detections.save(out / DETECTIONS_FILE, key)
                if progress is not None:
                    progress("detect", position, total)
            if first is None:
                raise InputError(part.info.path, None, "no frame in the selected range")
    detections.save(out / DETECTIONS_FILE, key)
    return detections


def _detect_frame(tracker, frame, size, detections: Detections, writer, position: int, camera: int,
                  clip: int) -> None:
    """Find the face in one frame, add it to ``detections``, and give the frame's image and mask to
    ``writer`` (a :class:`.frame_writer.FrameWriter`; as timestep ``position`` of ``camera``)."""
    height, width = frame.rgb.shape[:2]
    result = tracker(frame.rgb)
    face = result.face
    scale = np.array([size[0] / width, size[1] / height, size[0] / width], np.float32)
    landmarks = face.landmarks * scale if face is not None else np.full((478, 3), np.nan, np.float32)
    detections.append(landmarks, face.presence if face is not None else 0.0, result.faces, frame.time,
                      frame.index, size, clip)
    mask = result.mask if result.mask is not None else np.ones((height, width), np.float32)
    writer.add(frame.rgb, mask, size, position, camera)


def _fit(out, model, detections: Detections, settings: TrackSettings, info, progress):
    from ..camera import focal_from_35mm
    from .fit import Observations, fit_landmarks

    embedding, columns = _embedding(model)
    points = detections.landmarks[:, columns, :2].astype(np.float64)  # (T,L,2)
    confidence = np.repeat(detections.presence[:, None], len(columns), 1).astype(np.float64)
    confidence[~np.isfinite(points).all(-1)] = 0
    width, height = (int(v) for v in detections.sizes[0])  # the capture's first frame
    several = len(info.clips) > 1
    sizes = None if detections.one_size else detections.sizes
    photos = info.kind == "photos"
    observations = Observations(np.nan_to_num(points), confidence, width, height, embedding, sizes,
                                detections.clips if several else None, photos)
    focals = []
    for number, clip_size in enumerate(observations.clip_sizes()):  # one for a video or photos
        if settings.focal_px is not None:  # given at the input's size (its first frame's, upright): one lens
            focals.append(settings.focal_px * math.hypot(*clip_size) / math.hypot(info.width, info.height))
            continue
        clip_info = info.clips[number] if several else info
        lens = info.photos[0].focal_35mm if photos and info.photos else clip_info.focal_35mm
        focals.append(focal_from_35mm(lens, *clip_size) if lens else None)  # the file's lens, or estimated
    photometric = settings.fit.photometric.resolved(photos).steps > 0
    return fit_landmarks(model, observations, dataclasses.replace(settings.fit, focal=tuple(focals)),
                         progress=None if progress is None else lambda done, total, _rms: progress("fit", done, total),
                         brightness=_brightness(out, detections, photos) if photometric else None)


def _brightness(out: pathlib.Path, detections: Detections, photos: bool):
    """The brightness of the capture's images as written: ``(T,H,W)``, or a list of ``(H,W)`` for
    photos of several sizes (0 where a frame found no face: the photometric stage leaves those out)."""
    from ..io.image import read_image
    from .photometric import brightness

    sizes = [(int(height), int(width)) for width, height in detections.sizes]
    frames = (np.zeros((len(sizes), *sizes[0]), np.float32) if detections.one_size  # one array: a long clip's
              else [np.zeros(size, np.float32) for size in sizes])
    for t in np.nonzero(detections.presence > 0)[0]:
        camera = _camera_number(int(detections.clips[t]), int(t), photos)
        frames[t] = brightness(read_image(out / layout.image_path(int(t), camera)))
    return frames


def _embedding(model):
    """The points fitted: where they lie on the model's mesh, and which of the detector's 478 each is.

    A model with the procedural head's triangles: MediaPipe's own mesh points, those found stable on
    that mesh, and the iris centres, which give the gaze (:mod:`.mediapipe_embedding`). Any other
    model: the 51 iBUG points fixed on the face, each the mesh point
    :data:`.mediapipe_ibug68.IBUG68_FROM_MESH` names."""
    from ..flame.landmarks import STATIC_IBUG, model_landmarks
    from .mediapipe_embedding import model_mediapipe_embedding
    from .mediapipe_ibug68 import IBUG68_FROM_MESH

    faces = model.faces.numpy()
    dense = model_mediapipe_embedding(faces)
    if dense is not None:
        return dense, dense.ibug
    embedding = model_landmarks(faces)
    if embedding is None:
        raise InputError(None, "landmarks", "no landmark embedding for this head model (see docs/flame.md)")
    embedding = embedding.subset(STATIC_IBUG)
    return embedding, np.asarray(IBUG68_FROM_MESH)[embedding.ibug]


def _write_capture(out, fit, detections: Detections, head_file, model, video: bool, progress) -> dict:
    from ..data.landmarks import write_landmark_file
    from .detect import ibug68

    frames = len(detections.presence)
    seen = detections.presence > 0
    clips = detections.clips
    test = np.zeros(frames, bool)  # the last tenth of each clip (photos: of all)
    for clip in np.unique(clips):
        mine = np.nonzero(clips == clip)[0]
        test[mine[len(mine) - max(1, round(TEST_FRACTION * len(mine))):] if len(mine) > 1 else []] = True
    camera_ids = [_camera_id(int(clips[t])) if video else f"photo{t:03d}" for t in range(frames)]
    with CaptureWriter(out, n_vertices=model.n_vertices) as writer:
        for t in range(frames):
            writer.write_flame_params(t, fit.frame(t))
            if seen[t]:
                writer.record_frame(t, fit.camera_of(t, camera_ids[t]), split="test" if test[t] else "train",
                                    camera_index=_camera_number(int(clips[t]), t, not video))
            if progress is not None:
                progress("write", t + 1, frames)
    rows = np.concatenate([ibug68(detections.landmarks), np.repeat(detections.presence[:, None, None], 68, 1)], -1)
    for camera_id in sorted(set(camera_ids)):
        mine = np.array([cid == camera_id for cid in camera_ids]) & seen
        width, height = (int(v) for v in detections.sizes[np.argmax(mine) if mine.any() else 0])
        table = np.where(mine[:, None, None], rows, np.array([-width, -height, -1.0]))  # -1 rows once divided
        write_landmark_file(out, camera_id, table, width, height)  # VHAP's row of -1: no face (or another camera's)
    lost = [int(t) for t in np.nonzero(~seen)[0]]
    rms = fit.reprojection_px
    return {"frames": frames, "size": [int(v) for v in detections.sizes[0]], "one_size": detections.one_size,
            "focal_px": round(float(fit.camera.fx), 2),
            "lost_frames": lost, "two_faces_frames": [int(t) for t in np.nonzero(detections.faces > 1)[0]],
            "reprojection_px": {"mean": round(float(rms[seen].mean()), 3), "max": round(float(rms[seen].max()), 3),
                                "per_frame": [round(float(r), 3) for r in rms]},
            "splits": {"train": int((seen & ~test).sum()), "test": int((seen & test).sum())},
            "head_model": pathlib.Path(head_file).name,
            "input_frames": [int(i) for i in detections.indices]}
