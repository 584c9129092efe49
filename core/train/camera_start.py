"""Where a run's trainable cameras start: offsets, delays and colours built for the capture's
training cameras, started from a cameras file (an earlier round's or run's, with the delays and
colours beside it) or solved from the capture's landmark files.

A fresh run starts them here; a resumed run builds them the same way and reloads their values from
its checkpoint.
"""

from __future__ import annotations

import pathlib

from ..avatar.camera_colour import read_camera_colours
from ..data.camera_file import read_cameras, write_cameras
from ..errors import InputError
from ..run.names import COLOURS_FILE, DELAYS_FILE
from .camera_colour import CameraColours
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


def build_camera_colours(config: TrainConfig, data, fresh: bool = False) -> CameraColours | None:
    """The training cameras' colours when ``[cameras] colour`` is on; a fresh run whose cameras
    start from a file starts from the colours beside it, as its delays do."""
    if not config.cameras.colour:
        return None
    colours = CameraColours({f.camera_id for f in data.frames})
    start = config.cameras.start
    if fresh and start and start != LANDMARKS_START:
        beside = pathlib.Path(start).parent / COLOURS_FILE
        if beside.exists():
            colours.start_from(read_camera_colours(beside))
            colours.fix_gauge()
    return colours


def camera_state(offsets, delays, colours) -> dict:
    """The checkpoint's entries of the learned camera parts a run has (``cameras``, ``delays``,
    ``colours``)."""
    parts = {"cameras": offsets, "delays": delays, "colours": colours}
    return {name: part.state() for name, part in parts.items() if part is not None}


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


def build_cameras(config: TrainConfig, data, timesteps, head_source: pathlib.Path | None = None,
                  landmarks_file: pathlib.Path | None = None) -> tuple:
    """The learned camera parts of a run, ``(offsets, delays, colours)``, each None where the
    config has it off. ``head_source``: a fresh run's head model (its parts start where the config
    says); None for a resumed run, which reloads them with :func:`load_cameras`."""
    fresh = head_source is not None
    return (build_camera_offsets(config, data, head_source, landmarks_file),
            build_camera_delays(config, data, timesteps, fresh), build_camera_colours(config, data, fresh))


# Each learned part's checkpoint entry, its [cameras] switch and what it is called in errors.
_CHECKPOINT_PARTS = (("cameras", "refine", "camera offsets"), ("delays", "delays", "camera delays"),
                     ("colours", "colour", "camera colours"))


def load_cameras(state: dict, parts: tuple, source) -> None:
    """Reload a resumed run's learned camera ``parts`` (``(offsets, delays, colours)``, None where
    off) from its checkpoint ``state`` (``source``: the checkpoint folder, for errors): a checkpoint
    without those the config asks for is refused."""
    for (name, switch, label), part in zip(_CHECKPOINT_PARTS, parts):
        if part is None:
            continue
        if name not in state:
            raise InputError(source, name, f"the checkpoint holds no {label} (the run was started without "
                                           f"[cameras] {switch})")
        part.load(state[name], source)
