"""`track` on footage that goes wrong: a face lost for a stretch, no face at all, a folder in the way."""

import json

import numpy as np
import pytest

from mogaface.core.errors import InputError
from mogaface.core.io.video import VideoWriter
from mogaface.core.track.decode import FrameSelection, open_footage
from mogaface.core.track.fit import FitSettings
from mogaface.core.track.pipeline import TrackSettings, track_footage

FAST = TrackSettings(size=None, fit=FitSettings(steps=5))


def rewrite(source, out, blank) -> None:
    """``source``'s frames into a new clip, frames ``blank`` replaced by a grey wall (no face)."""
    frames = [frame.rgb for frame in open_footage(source).frames(FrameSelection())]
    height, width = frames[0].shape[:2]
    with VideoWriter(out, width, height, 30.0) as writer:
        for index, rgb in enumerate(frames):
            writer.write(np.full_like(rgb, 128) if index in blank else rgb)


def test_a_stretch_without_a_face_keeps_its_timesteps_marked_and_out_of_the_splits(handheld, tmp_path):
    clip = tmp_path / "lost.mp4"
    rewrite(handheld / "footage" / "clip.mp4", clip, blank={4, 5, 6})
    report = track_footage(clip, tmp_path / "cap", FAST)
    assert report["frames"] == 12 and report["lost_frames"] == [4, 5, 6]
    written = json.loads((tmp_path / "cap" / "tracking.json").read_text())
    assert written["lost_frames"] == [4, 5, 6]
    listed = {entry["timestep_index"] for name in ("train", "test")
              for entry in json.loads((tmp_path / "cap" / f"transforms_{name}.json").read_text())["frames"]}
    assert listed == set(range(12)) - {4, 5, 6}  # nothing trains or is scored on an interpolated guess
    assert (tmp_path / "cap" / "flame_param" / "00005.npz").is_file()  # the timestep is kept
    from mogaface.core.data.capture import Capture

    capture = Capture.open(tmp_path / "cap")
    rgb, mask = capture.load_image(next(iter(capture.frames("train"))))
    wall = mask < 0.01  # the images are stored on white through the person's mask, as training takes them
    assert wall.mean() > 0.1 and (rgb[wall] > 0.98).all()


def test_footage_without_any_face_is_refused_by_name(handheld, tmp_path):
    clip = tmp_path / "wall.mp4"
    rewrite(handheld / "footage" / "clip.mp4", clip, blank=set(range(12)))
    with pytest.raises(InputError, match="wall.mp4: no face was found in any frame"):
        track_footage(clip, tmp_path / "cap", FAST)
    assert not (tmp_path / "cap" / "transforms_train.json").exists()  # no reader takes the folder


def test_an_output_that_is_not_an_empty_folder_is_refused_before_any_work(handheld, tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "mine.txt").write_text("keep")
    with pytest.raises(InputError, match="is not empty"):
        track_footage(handheld / "footage" / "clip.mp4", tmp_path / "full", FAST)
    assert (tmp_path / "full" / "mine.txt").read_text() == "keep"
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="file: is a regular file; expected a folder for the outputs"):
        track_footage(handheld / "footage" / "clip.mp4", tmp_path / "file", FAST)


def test_an_interrupted_track_resumes_from_its_saved_detections(handheld, tmp_path, monkeypatch):
    """Stopped part-way (Ctrl-C), the folder has no split files (no reader takes it) and the
    detections saved so far; the same command goes on from there and ends as a whole run does."""
    from mogaface.core.track import pipeline

    monkeypatch.setattr(pipeline, "SAVE_EVERY", 4)
    seen = []

    def stop_at_seven(stage, done, total):
        seen.append((stage, done))
        if stage == "detect" and done == 7:
            raise KeyboardInterrupt

    clip, out = handheld / "footage" / "clip.mp4", tmp_path / "cap"
    with pytest.raises(KeyboardInterrupt):
        track_footage(clip, out, FAST, progress=stop_at_seven)
    assert not (out / "transforms_train.json").exists() and (out / pipeline.DETECTIONS_FILE).is_file()
    seen.clear()
    report = track_footage(clip, out, FAST, progress=lambda stage, done, total: seen.append((stage, done)))
    detected = [done for stage, done in seen if stage == "detect"]
    assert detected[0] == 5  # frames 0-3 were saved (every 4th frame) and are not detected again
    assert report["frames"] == 12 and (out / "transforms_train.json").is_file()
    assert not (out / pipeline.DETECTIONS_FILE).exists()
    with pytest.raises(InputError, match="is not empty"):  # a finished capture is never tracked over
        track_footage(clip, out, FAST)


def test_a_real_photograph_is_found_fitted_and_written(tmp_path):
    """The astronaut (a real photograph that ships with scikit-image): one face found, the head model
    fitted to its 398 MediaPipe points within a few pixels, a capture written."""
    from PIL import Image
    from skimage import data

    (tmp_path / "photos").mkdir()
    Image.fromarray(data.astronaut()).save(tmp_path / "photos" / "astronaut.png")
    report = track_footage(tmp_path / "photos", tmp_path / "cap", TrackSettings(size=None))
    assert report["frames"] == 1 and report["lost_frames"] == [] and report["two_faces_frames"] == []
    assert report["reprojection_px"]["mean"] < 4.0  # 2.4 px at 512 px when this was written
    assert (tmp_path / "cap" / "transforms_train.json").is_file()
