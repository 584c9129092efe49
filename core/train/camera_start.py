"""Where a run's trainable cameras start: offsets and delays built for the capture's training
cameras, started from a cameras file (an earlier round's or run's, with the delays beside it) or
solved from the capture's landmark files.

A fresh run starts them here; a resumed run builds them the same way and reloads their values from
its checkpoint.
"""

from __future__ import annotations

import pathlib

from ..data.camera_file import read_cameras, write_cameras
from ..errors import InputError
from ..run.names import DELAYS_FILE
from .camera_delays import CameraDelays, read_delays
from .camera_refine import CameraOffsets
from .config import LANDMARKS_START, TrainConfig


def build_camera_offsets(config: TrainConfig, data, head_source: pathlib.Path | None = None,
                         landmarks_file: pathlib.Path | None = None) -> CameraOffsets | None:
    """The training cameras' offsets when ``[cameras] refine`` is on (each camera as first met).
    ``head_source``: the head model a fresh run starts from (its start is set here; a restored
    run reloads its offsets from the checkpoint). ``landmarks_file``: where the cameras solved from
    the landmarks are written (None: not written, e.g. on a rank that does not write)."""
    if not config.cameras.refine:
        return None
    cameras = {}
    for frame in data.frames:
        cameras.setdefault(frame.camera_id, data.capture.camera(frame))
    offsets = CameraOffsets(cameras, config.cameras.gauge)
    start = config.cameras.start
    if start and head_source is not None:
        offsets.start_from(start_cameras(config, data, head_source, landmarks_file), start)
        offsets.fix_gauge()
    return offsets


def build_camera_delays(config: TrainConfig, data, timesteps, fresh: bool = False) -> CameraDelays | None:
    """The training cameras' delays when ``[cameras] delays`` is on. A fresh run whose cameras
    start from a file (an earlier round's, or run's) starts from the delays beside it: a new
    round keeps what the last one learned, as its cameras do."""
    if not config.cameras.delays:
        return None
    delays = CameraDelays({f.camera_id for f in data.frames}, timesteps, data.capture.sequences)
    start = config.cameras.start
    if fresh and start and start != LANDMARKS_START:
        beside = pathlib.Path(start).parent / DELAYS_FILE
        if beside.exists():
            delays.start_from(read_delays(beside))
    return delays


def start_cameras(config: TrainConfig, data, head_source: pathlib.Path,
                  landmarks_file: pathlib.Path | None = None) -> dict:
    """The cameras a refining run starts from: a cameras file, or ``"landmarks"``: solved from the
    capture's landmark files (written to ``landmarks_file``, ``RUN/cameras_landmarks.json``) on
    ``head_source``, the model file as the user gave it (an embedding file may lie beside it)."""
    start = config.cameras.start
    if start != LANDMARKS_START:
        return read_cameras(pathlib.Path(start))
    from ..flame.landmarks import read_embedding
    from .landmark_cameras import solve_cameras

    embedding = config.cameras.embedding
    solved = solve_cameras(data.capture, head_source, read_embedding(embedding) if embedding else None,
                           gauge=config.cameras.gauge).cameras
    if landmarks_file is not None:
        write_cameras(landmarks_file, solved)
    return solved


def load_cameras(state: dict, offsets: CameraOffsets | None, delays: CameraDelays | None, source) -> None:
    """Reload a resumed run's camera delays and offsets from its checkpoint ``state`` (``source``:
    the checkpoint folder, for errors): a checkpoint without those the config asks for is refused."""
    if delays is not None:
        if "delays" not in state:
            raise InputError(source, "delays",
                             "the checkpoint holds no camera delays (the run was started without [cameras] delays)")
        delays.load(state["delays"], source)
    if offsets is not None:
        if "cameras" not in state:
            raise InputError(source, "cameras", "the checkpoint holds no camera offsets "
                                                "(the run was started without [cameras] refine)")
        offsets.load(state["cameras"], source)
