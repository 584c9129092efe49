"""Synthetic phone footage: the clip and photos read back as rendered, the truth aside and exact."""

import hashlib
import json
import sys

import numpy as np
import pytest

from mogaface.core.data.camera_file import read_cameras
from mogaface.core.data.footage import FootageScene, make_footage
from mogaface.core.data.footage_settings import FootageSettings
from mogaface.core.errors import InputError
from mogaface.core.flame.model import FlameModel
from mogaface.core.io.npz import load_npz
from mogaface.core.track.decode import open_footage
from mogaface.core.track.inputs import FrameSelection

TINY = dict(width=64, height=112, fps=30.0, seconds=0.4, supersample=1, novel_views=2, novel_every=6, novel_size=32)


def psnr(a, b) -> float:
    return float(10 * np.log10(255.0**2 / np.mean((a.astype(np.float64) - b) ** 2)))


def scene_of(truth) -> FootageScene:
    info = json.loads((truth / "footage.json").read_text())
    return FootageScene(FootageSettings(**info["settings"]), FlameModel.load(truth / info["model_file"]))


def tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def flagged(tmp_path_factory, procedural_head_pkl):
    settings = FootageSettings(kind="fixed", rotation_flag=True, seed=4, **TINY)
    return make_footage(tmp_path_factory.mktemp("fixed"), settings, model_path=procedural_head_pkl, progress=False)


def test_the_footage_folder_holds_only_the_clip_and_the_truth_is_aside(handheld):
    assert tree(handheld / "footage") == ["clip.mp4"]
    truth = tree(handheld / "truth")
    frames = [f"flame_param/{i:05d}.npz" for i in range(12)]
    novel = [f"novel_views/{kind}/{i:05d}_novel{k:02d}.png" for kind in ("images", "masks") for i in (0, 6) for k in (0, 1)]
    assert truth == sorted(["cameras.json", "footage.json", "head.pkl", "script.json", "novel_views/cameras.json",
                            *frames, *novel])
    assert (handheld / "sheet.png").is_file()


def test_the_clip_reads_back_as_rendered(handheld):
    video = open_footage(handheld / "footage" / "clip.mp4")
    info = video.info
    assert (info.frame_count, info.fps, info.width, info.height, info.codec) == (12, 30.0, 64, 112, "h264")
    scene = scene_of(handheld / "truth")
    frames = {f.index: f.rgb for f in video.frames()}
    assert sorted(frames) == list(range(12))
    for i in (0, 7):
        assert psnr(frames[i], scene.image(i)) > 30
    # the lens the clip's metadata names is the truth's
    cameras = read_cameras(handheld / "truth" / "cameras.json")
    assert info.focal_35mm == 26.0 and cameras["00000"].fx == pytest.approx(info.focal_px)


def test_the_truth_is_what_was_rendered(handheld):
    truth = handheld / "truth"
    scene = scene_of(truth)
    cameras = read_cameras(truth / "cameras.json")
    assert sorted(cameras) == [f"{i:05d}" for i in range(12)]
    for i in (0, 11):
        stored = load_npz(truth / "flame_param" / f"{i:05d}.npz")
        for key, value in scene.params(i).items():
            assert np.allclose(stored[key].reshape(-1), value), key
        assert np.allclose(cameras[f"{i:05d}"].w2c, scene.cameras[i].w2c)
        assert np.allclose(cameras[f"{i:05d}"].K, scene.cameras[i].K)
        # the head is in the picture: every vertex projects inside the frame, in front of the camera
        vertices, _ = scene.mesh(i)
        uv, depth = cameras[f"{i:05d}"].project(vertices)
        assert depth.min() > 0.2 and uv.min() > 0 and uv[:, 0].max() < 64 and uv[:, 1].max() < 112
    info = json.loads((truth / "footage.json").read_text())
    assert info["times"] == pytest.approx(np.arange(12) / 30) and len(info["exposure_gain"]) == 12
    assert info["novel_views"]["frames"] == [0, 6]
    novel = read_cameras(truth / "novel_views" / "cameras.json")
    centres = np.array([c.center - scene.target for c in novel.values()])
    azimuth = np.degrees(np.arctan2(centres[:, 0], centres[:, 2]))
    assert np.all(np.abs(azimuth) > 60)  # the clip orbits within ±40°
    script = json.loads((truth / "script.json").read_text())
    assert script["segments"][0]["sequence"] == "SPEECH" and script["head"] == "still"


def test_the_same_seed_gives_the_same_files(handheld, tmp_path, procedural_head_pkl):
    again = tmp_path / "again"
    settings = FootageSettings(seed=3, **{**TINY, "novel_views": 2})
    make_footage(again, settings, model_path=procedural_head_pkl, progress=False)

    def digests(folder):
        return {name: hashlib.sha256((folder / name).read_bytes()).hexdigest() for name in tree(folder)}

    first = digests(handheld / "footage") | digests(handheld / "truth")
    assert first == digests(again / "footage") | digests(again / "truth")


def test_a_rotation_flag_clip_reads_portrait_and_the_head_turns(flagged):
    video = open_footage(flagged.files[0])
    assert (video.info.stored_width, video.info.stored_height, video.info.orientation) == (112, 64, 6)
    scene = scene_of(flagged.truth)
    frames = {f.index: f.rgb for f in video.frames(FrameSelection(stride=11))}
    assert sorted(frames) == [0, 11] and all(psnr(frames[i], scene.image(i)) > 30 for i in frames)
    assert len({c.w2c.tobytes() for c in scene.cameras}) == 1  # a still camera
    long = FootageScene(FootageSettings(kind="fixed", seconds=8.0, fps=10.0, **{k: v for k, v in TINY.items()
                                                                            if k not in ("seconds", "fps")}),
                        scene.model)
    yaw = np.degrees(long.head["rotation"][:, 1])
    assert 33 < yaw.max() <= 35 and -35 <= yaw.min() < -33


def test_handheld_orbits_a_still_head(flagged):
    scene = FootageScene(FootageSettings(kind="handheld", seconds=8.0, fps=10.0,
                                         **{k: v for k, v in TINY.items() if k not in ("seconds", "fps")}),
                         FlameModel.load(flagged.truth / "head.pkl"))
    centres = np.array([c.center - scene.target for c in scene.cameras])
    azimuth = np.degrees(np.arctan2(centres[:, 0], centres[:, 2]))
    assert 36 < azimuth.max() < 44 and -44 < azimuth.min() < -36
    assert not np.any(scene.head["rotation"]) and not np.any(scene.head["translation"])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert steps.max() < 0.05  # smooth: centimetres a frame at 10 fps


def test_photos_read_upright_in_mixed_sizes(tmp_path, procedural_head_pkl):
    settings = FootageSettings(kind="photos", photos=3, width=48, height=64, supersample=1, novel_views=1,
                               novel_size=32)
    folders = make_footage(tmp_path / "photos", settings, model_path=procedural_head_pkl, progress=False)
    assert tree(folders.footage) == ["IMG_0001.jpg", "IMG_0002.jpg", "IMG_0003.jpg"]
    photos = open_footage(folders.footage)
    cameras = read_cameras(folders.truth / "cameras.json")
    assert [(p.width, p.height, p.orientation) for p in photos.info.photos] == [(48, 64, 6), (64, 48, 1), (36, 48, 1)]
    assert [(c.width, c.height) for c in cameras.values()] == [(48, 64), (64, 48), (36, 48)]
    assert all(p.focal_35mm == 26.0 for p in photos.info.photos)
    scene = scene_of(folders.truth)
    for frame in photos.frames():
        assert psnr(frame.rgb, scene.image(frame.index)) > 28


def test_outputs_that_would_mix_truth_and_footage_are_refused(tmp_path, procedural_head_pkl):
    with pytest.raises(InputError, match="outside the footage folder"):
        make_footage(tmp_path / "a", FootageSettings(**TINY), truth=tmp_path / "a" / "footage" / "truth",
                     model_path=procedural_head_pkl, progress=False)
    (tmp_path / "b" / "footage").mkdir(parents=True)
    (tmp_path / "b" / "footage" / "old.mp4").write_bytes(b"x")
    with pytest.raises(InputError, match="is not empty"):
        make_footage(tmp_path / "b", FootageSettings(**TINY), model_path=procedural_head_pkl, progress=False)
    with pytest.raises(InputError, match="width"):
        FootageSettings(width=63).check()


def test_reading_and_tracking_the_footage_never_open_the_truth(handheld, tmp_path):
    """The clip is read, and tracked into a capture (face, landmarks, fit, files), without one open
    inside the truth folder."""
    from mogaface.core.track.fit import FitSettings
    from mogaface.core.track.photometric import PhotometricSettings
    from mogaface.core.track.pipeline import TrackSettings, refit, track_footage

    record = {"on": True, "paths": []}

    def hook(event, args):
        if record["on"] and event == "open" and args and isinstance(args[0], str | bytes):
            record["paths"].append(str(args[0]))

    sys.addaudithook(hook)  # hooks stay for the process: this one records only while "on"
    try:
        video = open_footage(handheld / "footage" / "clip.mp4")
        list(video.frames(FrameSelection(end=2)))
        report = track_footage(handheld / "footage" / "clip.mp4", tmp_path / "tracked",
                               TrackSettings(size=None, fit=FitSettings(steps=10, photometric=PhotometricSettings(steps=20))),
                               keep_detections=True)
        again = refit(tmp_path / "tracked", TrackSettings(size=None, fit=FitSettings(
            steps=3, photometric=PhotometricSettings(steps=20))))  # as settings are chosen
    finally:
        record["on"] = False
    assert any("clip.mp4" in path for path in record["paths"])
    assert not [path for path in record["paths"] if "truth" in path]
    assert report["frames"] == again["frames"] == 12 and (tmp_path / "tracked" / "transforms_train.json").is_file()
    assert again["reprojection_px"] != report["reprojection_px"]  # fitted anew from the same detections
