"""Benchmark of face tracking's detection step: milliseconds per frame, stage by stage, at 720×1280.

The frame: scikit-image's astronaut photograph enlarged into a portrait 720×1280 frame (a phone
video's size; the face about 240 px wide). Each stage's model input has a fixed size, so the times
hardly depend on the content. Stages: the face detector (every frame), the 468-point mesh, the
two irises, the person mask (model and resizing to the frame), and the whole tracked frame
(:class:`~mogaface.core.track.detect.FaceTracker`, the region from the previous frame), with and
without the mask. Medians of ``repeats`` runs after two warm-up runs; the load average is reported
beside them, since other processes share the cores.

The models are not all of ``track``'s cost: ``track_loop`` times its own loop on a short clip of the
frame (decoding, detecting, and writing each frame's image and mask at 512 px, which its writer's
thread overlaps with the next frame), and ``write`` that writing alone, in line; their ratio to the
whole tracked frame says what the rest costs.
"""

from __future__ import annotations

import os
import pathlib
import platform
import tempfile
import time

from .timing import median_ms


def test_frame():
    """The astronaut, enlarged to 1280 px high and cut to 720 px wide around the face (uint8)."""
    import numpy as np
    from skimage import data
    from skimage.transform import resize

    large = resize(data.astronaut(), (1280, 1280), order=1, anti_aliasing=False)
    return (large[:, 200:920] * 255 + 0.5).astype(np.uint8)


def track_loop_ms(frame, threads: int, frames: int) -> float:
    """ms per frame of ``track``'s loop (decode, detect, write) over a clip of ``frames`` frames of
    ``frame``, moving a few pixels a frame; the trackers' set-up is counted in."""
    import numpy as np

    from mogaface.core.io.video import VideoWriter
    from mogaface.core.track.decode import open_footage
    from mogaface.core.track.inputs import FrameSelection
    from mogaface.core.track.pipeline import TrackSettings, _detect

    with tempfile.TemporaryDirectory() as folder:
        clip = pathlib.Path(folder) / "clip.mp4"
        with VideoWriter(clip, frame.shape[1], frame.shape[0], 30.0) as video:
            for index in range(frames):
                video.write(np.roll(frame, round(12 * np.sin(index / 4)), axis=1))
        footage = open_footage(clip)
        started = time.perf_counter()
        _detect(footage, pathlib.Path(folder) / "capture", "bench", TrackSettings(threads=threads), FrameSelection(),
                False, None)
        return 1000 * (time.perf_counter() - started) / frames


def run(threads: int = 2, quick: bool = False) -> dict:
    from mogaface.core.track import mediapipe_face as mf
    from mogaface.core.track.detect import FaceTracker
    from mogaface.core.track.frame_writer import write_frame

    repeats = 10 if quick else 50

    def timed(call) -> float:
        return round(median_ms(call, repeats, warmups=2), 2)

    frame = test_frame()
    tracker = FaceTracker(threads=threads)
    first = tracker(frame)
    if first.face is None:
        raise RuntimeError("no face found in the benchmark frame")
    roi = mf.roi_from_points(first.face.landmarks[:468], *mf.FACE_ROTATION_POINTS, mf.FACE_ROI_SCALE)
    mesh, _ = tracker.mesh_points(frame, roi)
    stages = {
        "detect": timed(lambda: tracker.detect(frame)),
        "mesh": timed(lambda: tracker.mesh_points(frame, roi)),
        "irises": timed(lambda: tracker.irises(frame, mesh)),
        "mask": timed(lambda: tracker.segment(frame)),
    }
    with tempfile.TemporaryDirectory() as folder:
        stages["write"] = timed(lambda: write_frame(pathlib.Path(folder), frame, first.mask, (288, 512), 0, 0))
    whole = timed(lambda: tracker(frame))
    no_mask = FaceTracker(threads=threads, mask=False)
    no_mask(frame)
    landmarks_only = timed(lambda: no_mask(frame))
    loop = round(track_loop_ms(frame, threads, 30 if quick else 90), 2)
    return {
        "frame": f"{frame.shape[1]}x{frame.shape[0]}",
        "threads": threads,
        "repeats": repeats,
        "ms_per_stage": stages,
        "ms_per_frame": whole,
        "ms_per_frame_without_mask": landmarks_only,
        "frames_per_second": round(1000.0 / whole, 1),
        "ms_per_frame_track_loop": loop,
        "track_loop_over_frame": round(loop / whole, 2),
        "load_average": open("/proc/loadavg").read().split()[:3] if os.path.exists("/proc/loadavg") else None,
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
    }
