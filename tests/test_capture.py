"""Capture datasets: write, read back, validate, and refuse bad data with a clear message."""

import json

import numpy as np
import pytest

from mogaface.core.camera import Camera, intrinsics_matrix, opencv_w2c_to_opengl_c2w
from mogaface.core.cli import main as cli_main
from mogaface.core.data.capture import Capture
from mogaface.core.data.validate import validate_capture
from mogaface.core.data.writer import CaptureWriter
from mogaface.core.errors import CaptureError
from mogaface.core.io.image import write_png
from mogaface.core.io.npz import save_npz

W, H = 16, 12  # the smallest size a capture may have is 11 px a side (MIN_IMAGE_SIDE)


def _cameras():
    a = Camera.look_at((0.0, 0.0, 1.0), (0, 0, 0), width=W, height=H, fov_x=0.6, camera_id="cam_a")
    # Off-centre principal point and non-square pixels: per-frame intrinsics must survive.
    b = Camera.look_at((0.8, 0.1, 0.6), (0, 0, 0), width=W, height=H, fx=14.0, fy=15.5, cx=5.25, cy=3.5, camera_id="cam_b")
    return [a, b]


def _params(rng, n_shape=10, n_expr=5):
    return {
        "shape": rng.normal(size=n_shape).astype(np.float32),
        "expr": rng.normal(size=n_expr).astype(np.float32),
        "rotation": rng.normal(size=3).astype(np.float32),
        "neck_pose": rng.normal(size=3).astype(np.float32),
        "jaw_pose": rng.normal(size=3).astype(np.float32),
        "eyes_pose": rng.normal(size=6).astype(np.float32),
        "translation": rng.normal(size=3).astype(np.float32),
        "static_offset": rng.normal(size=(4, 3)).astype(np.float32) * 0.01,
    }


def make_capture(root, seed=0):
    """3 timesteps x 2 cameras: train = t0,t1 on both; val = t2 cam_a; test = t2 cam_b."""
    rng = np.random.default_rng(seed)
    truth = {"images": {}, "params": {}}
    cams = _cameras()
    with CaptureWriter(root) as writer:
        for t in range(3):
            params = _params(rng)
            writer.write_flame_params(t, params)
            truth["params"][t] = params
            for cam in cams:
                split = "train" if t < 2 else ("val" if cam.camera_id == "cam_a" else "test")
                rgb = rng.random((H, W, 3)).astype(np.float32)
                mask = (rng.random((H, W)) > 0.5).astype(np.float32)
                writer.add_frame(t, cam, rgb, mask, split=split, sequence="SEQ-A" if t < 2 else "SEQ-B")
                truth["images"][(t, cam.camera_id)] = (rgb, mask)
        writer.write_canonical_flame_params(_params(rng))
    return truth


@pytest.fixture
def capture_dir(tmp_path):
    root = tmp_path / "cap"
    truth = make_capture(root)
    return root, truth


def test_round_trip(capture_dir):
    root, truth = capture_dir
    cap = Capture.open(root)
    assert list(cap.splits) == ["train", "val", "test"]
    assert [len(cap.frames(s)) for s in cap.splits] == [4, 1, 1]
    assert cap.timesteps == [0, 1, 2]
    assert cap.sequences == {"SEQ-A": [0, 1], "SEQ-B": [2]}
    assert list(cap.cameras) == ["cam_a", "cam_b"]
    for original in _cameras():
        read = cap.cameras[original.camera_id]
        np.testing.assert_allclose(read.K, original.K, atol=1e-9)
        np.testing.assert_allclose(read.w2c, original.w2c, atol=1e-9)
        pts = np.random.default_rng(3).normal(size=(6, 3)) * 0.1
        np.testing.assert_allclose(read.project(pts)[0], original.project(pts)[0], atol=1e-7)
    for frame in cap.frames():
        rgb, mask = cap.load_image(frame)
        want_rgb, want_mask = truth["images"][(frame.timestep_index, frame.camera_id)]
        assert rgb.dtype == np.float32 and rgb.shape == (H, W, 3) and mask.shape == (H, W)
        np.testing.assert_allclose(rgb, np.round(want_rgb * 255) / 255, atol=1e-6)
        np.testing.assert_array_equal(mask, want_mask)
        assert frame.file_path == f"images/{frame.timestep_index:05d}_{frame.camera_index:02d}.png"
    for t, params in truth["params"].items():
        read = cap.flame_params(t)
        assert set(read) == set(params)
        for key in params:
            np.testing.assert_array_equal(read[key], params[key])
    stacked = cap.flame_params_stacked()
    assert stacked["expr"].shape == (3, 5) and stacked["static_offset"].shape == (4, 3)
    assert cap.canonical_flame_params()["eyes_pose"].shape == (6,)


def test_written_files_follow_the_vhap_layout(capture_dir):
    root, _ = capture_dir
    doc = json.loads((root / "transforms_train.json").read_text())
    assert doc["camera_indices"] == [0, 1] and doc["timestep_indices"] == [0, 1]
    assert doc["w"] == W and doc["h"] == H and "fl_x" not in doc  # top level only where uniform
    frame = doc["frames"][0]
    for key in ("file_path", "fg_mask_path", "flame_param_path", "timestep_index", "timestep_id", "camera_index",
                "camera_id", "fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", "transform_matrix"):
        assert key in frame
    everything = json.loads((root / "transforms.json").read_text())
    assert len(everything["frames"]) == 6
    with np.load(root / "flame_param" / "00000.npz", allow_pickle=False) as npz:
        assert npz["shape"].shape == (10,) and npz["expr"].shape == (1, 5) and npz["static_offset"].shape == (1, 4, 3)
    # OpenGL camera-to-world: camera a sits at +z looking at the origin, so its -z axis points to -z.
    c2w = np.array(frame["transform_matrix"])
    np.testing.assert_allclose(c2w[:3, 3], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(c2w[:3, 2], [0, 0, 1], atol=1e-12)
    assert not list(root.rglob("*.partial*"))


def test_unbatched_flame_arrays_are_accepted(capture_dir):
    root, truth = capture_dir
    flat = {k: np.asarray(v) for k, v in truth["params"][1].items()}
    save_npz(root / "flame_param" / "00001.npz", flat)
    np.testing.assert_array_equal(Capture.open(root).flame_params(1)["jaw_pose"], flat["jaw_pose"])


def test_lru_cache_stays_bounded(capture_dir):
    root, _ = capture_dir
    per_image = H * W * 4 * 4  # rgb + mask float32
    cap = Capture.open(root, cache_bytes=2 * per_image + 10)
    assert cap.memory_bound_bytes == 2 * per_image + 10
    frames = cap.frames()
    for _ in range(3):
        for frame in frames:
            cap.load_image(frame)
            assert cap.cached_bytes <= cap.memory_bound_bytes
    assert cap.cached_bytes == 2 * per_image
    a = cap.load_image(frames[-1])
    assert cap.load_image(frames[-1])[0] is a[0]  # a hit returns the cached, read-only array
    assert not a[0].flags.writeable
    tiny = Capture.open(root, cache_bytes=10)
    tiny.load_image(frames[0])
    assert tiny.cached_bytes == 0


def test_the_image_alone_reads_no_mask_and_leaves_the_cache_to_the_loss(capture_dir, monkeypatch):
    root, _ = capture_dir
    cap = Capture.open(root)
    frame = cap.frames()[0]
    read = []
    original = cap._read
    monkeypatch.setattr(cap, "_read", lambda f, name: read.append(name) or original(f, name))
    rgb = cap.load_rgb(frame)
    assert read == ["file_path"] and cap.cached_bytes == 0 and not rgb.flags.writeable
    full, _ = cap.load_image(frame)
    np.testing.assert_array_equal(rgb, full)
    assert cap.load_rgb(frame) is full and read == ["file_path", "file_path", "fg_mask_path"]


def test_validate_summary_and_cli(capture_dir, capsys):
    root, _ = capture_dir
    summary = validate_capture(root)
    assert summary.views == 2 and summary.timesteps == 3 and summary.resolutions == [(W, H)]
    assert summary.sequences == {"SEQ-A": 2, "SEQ-B": 1}
    assert summary.splits["train"] == {"frames": 4, "views": 2, "timesteps": 2}
    assert summary.flame_sizes["expr"] == (5,) and summary.has_canonical
    assert cli_main(["check-capture", str(root)]) == 0
    out = capsys.readouterr().out
    assert "views: 2" in out and "timesteps: 3" in out and "SEQ-A" in out and f"{W}x{H}" in out
    (root / "images" / "00001_01.png").unlink()
    assert cli_main(["check-capture", str(root)]) == 2
    err = capsys.readouterr().err
    assert "00001_01.png" in err and "file_path" in err
    assert cli_main(["check-capture", str(root / "nowhere")]) == 2


# -- bad data: each case edits a good capture and names the file and field to expect ----------

def _edit_json(root, name, change):
    path = root / name
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _set_frame(index, key, value):
    def change(doc):
        doc["frames"][index][key] = value
    return change


def _del_frame(index, key):
    def change(doc):
        del doc["frames"][index][key]
    return change


def _bad_params(root, t, **changes):
    with np.load(root / "flame_param" / f"{t:05d}.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    for key, value in changes.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    save_npz(root / "flame_param" / f"{t:05d}.npz", arrays)


def _second_camera_b_intrinsics(doc):
    frame = next(f for f in doc["frames"] if f["camera_id"] == "cam_b" and f["timestep_index"] == 1)
    frame["fl_x"] += 1.0


def _drop_focal(doc):
    for entry in [doc] + doc["frames"]:
        entry.pop("fl_x", None)
        entry.pop("camera_angle_x", None)


BAD_CASES = {
    "missing image": (lambda r: (r / "images/00000_00.png").unlink(), "00000_00.png", "file_path"),
    "missing mask": (lambda r: (r / "fg_masks/00001_00.png").unlink(), "00001_00.png", "fg_mask_path"),
    "unreadable image": (lambda r: (r / "images/00000_01.png").write_bytes(b"garbage"), "00000_01.png", "file_path"),
    "missing flame file": (lambda r: (r / "flame_param/00001.npz").unlink(), "00001.npz", "flame_param_path"),
    "unreadable flame file": (lambda r: (r / "flame_param/00001.npz").write_bytes(b"zip?"), "00001.npz", "npz"),
    "missing split file": (lambda r: (r / "transforms_train.json").unlink(), "transforms_train.json", "not found"),
    "bad json": (lambda r: (r / "transforms_val.json").write_text("{"), "transforms_val.json", "JSON"),
    "parent path": (lambda r: _edit_json(r, "transforms_train.json", _set_frame(0, "file_path", "../x.png")),
                    "transforms_train.json", "frames[0].file_path"),
    "absolute path": (lambda r: _edit_json(r, "transforms_train.json", _set_frame(1, "fg_mask_path", "/etc/passwd")),
                      "transforms_train.json", "frames[1].fg_mask_path"),
    "windows path": (lambda r: _edit_json(r, "transforms_test.json", _set_frame(0, "flame_param_path", "C:\\x.npz")),
                     "transforms_test.json", "frames[0].flame_param_path"),
    "wrong shape": (lambda r: _bad_params(r, 1, jaw_pose=np.zeros((1, 4), np.float32)), "00001.npz", "jaw_pose"),
    "wrong dtype": (lambda r: _bad_params(r, 2, expr=np.zeros((1, 5), np.int64)), "00002.npz", "expr"),
    "nan": (lambda r: _bad_params(r, 0, translation=np.array([[0, np.nan, 0]], np.float32)), "00000.npz", "translation"),
    "inf": (lambda r: _bad_params(r, 0, shape=np.full(10, np.inf, np.float32)), "00000.npz", "shape"),
    "missing flame key": (lambda r: _bad_params(r, 1, neck_pose=None), "00001.npz", "neck_pose"),
    "sizes differ in time": (lambda r: _bad_params(r, 2, expr=np.zeros((1, 7), np.float32)), "00002.npz", "expr"),
    "pickled npz": (lambda r: np.savez(r / "flame_param/00000.npz", shape=np.array([object()], dtype=object)),
                    "00000.npz", "pickle"),
    "image size": (lambda r: write_png(r / "images/00001_01.png", np.zeros((H + 1, W, 3))), "00001_01.png", "w/h"),
    "mask size": (lambda r: write_png(r / "fg_masks/00002_00.png", np.zeros((H, W - 2))), "00002_00.png", "w/h"),
    "frame w": (lambda r: _edit_json(r, "transforms_val.json", _set_frame(0, "w", W + 4)), "transforms_val.json", "w"),
    "camera intrinsics differ": (lambda r: _edit_json(r, "transforms_train.json", _second_camera_b_intrinsics),
                                 "transforms_train.json", "fl_x"),
    "empty train split": (lambda r: _edit_json(r, "transforms_train.json", lambda d: d.update(frames=[])),
                          "transforms_train.json", "frames"),
    "grandparent path": (lambda r: _edit_json(r, "transforms_train.json",
                                              _set_frame(0, "file_path", "../../seq/images/00000_00.png")),
                         "transforms_train.json", "frames[0].file_path"),
    "sibling then up": (lambda r: _edit_json(r, "transforms_train.json",
                                             _set_frame(0, "flame_param_path", "../seq/../../x.npz")),
                        "transforms_train.json", "frames[0].flame_param_path"),
    "no frames key": (lambda r: _edit_json(r, "transforms_val.json", lambda d: d.pop("frames")), "transforms_val.json", "frames"),
    "no transform": (lambda r: _edit_json(r, "transforms_train.json", _del_frame(2, "transform_matrix")),
                     "transforms_train.json", "frames[2].transform_matrix"),
    "no timestep": (lambda r: _edit_json(r, "transforms_train.json", _del_frame(3, "timestep_index")),
                    "transforms_train.json", "frames[3].timestep_index"),
    "no file path": (lambda r: _edit_json(r, "transforms_train.json", _del_frame(0, "file_path")),
                     "transforms_train.json", "frames[0].file_path"),
    "non-rigid transform": (lambda r: _edit_json(r, "transforms_train.json",
                                                 _set_frame(0, "transform_matrix", (np.eye(4) * 2).tolist())),
                            "transforms_train.json", "frames[0].transform_matrix"),
    "camera index changes": (lambda r: _edit_json(r, "transforms_train.json", _set_frame(3, "camera_index", 5)),
                             "transforms_train.json", "frames[3].camera_index"),
    "no intrinsics": (lambda r: _edit_json(r, "transforms_val.json", _drop_focal), "transforms_val.json", "fl_x"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_data_names_file_and_field(capture_dir, case):
    root, _ = capture_dir
    damage, file_part, field_part = BAD_CASES[case]
    damage(root)
    with pytest.raises(CaptureError) as info:
        validate_capture(root)
    message = str(info.value)
    assert file_part in message, message
    assert field_part in message, message


def test_load_image_reports_wrong_size(capture_dir):
    root, _ = capture_dir
    write_png(root / "images/00000_00.png", np.zeros((H, W + 3, 3)))
    cap = Capture.open(root)
    with pytest.raises(CaptureError, match=r"00000_00.png.*w/h"):
        cap.load_image(cap.frames("train")[0])


def test_gaussian_avatars_style_file_without_optional_fields(tmp_path):
    """Top-level camera_angle_x only, no camera_id/timestep_id/fg masks: still readable."""
    root = tmp_path / "ga"
    cam = Camera(intrinsics_matrix(10.0, 10.0, W / 2, H / 2), np.eye(4), W, H)
    rgba = np.random.default_rng(0).random((H, W, 4)).astype(np.float32)
    write_png(root / "images/00000_00.png", rgba)
    save_npz(root / "flame_param/00000.npz", {k: v for k, v in _params(np.random.default_rng(1)).items()})
    doc = {
        "camera_angle_x": cam.fov_x,
        "w": W,
        "h": H,
        "frames": [{
            "file_path": "./images/00000_00.png",
            "flame_param_path": "flame_param/00000.npz",
            "timestep_index": 0,
            "camera_index": 0,
            "transform_matrix": opencv_w2c_to_opengl_c2w(cam.w2c).tolist(),
        }],
    }
    (root / "transforms_train.json").write_text(json.dumps(doc))
    summary = validate_capture(root)
    assert summary.splits == {"train": {"frames": 1, "views": 1, "timesteps": 1}}
    cap = Capture.open(root)
    np.testing.assert_allclose(cap.cameras["0"].K, cam.K)
    rgb, mask = cap.load_image(cap.frames()[0])
    np.testing.assert_allclose(mask, np.round(rgba[..., 3] * 255) / 255, atol=1e-6)
    assert cap.sequences == {}


def test_open_reads_no_pixels(capture_dir):
    root, _ = capture_dir
    for png in (root / "images").iterdir():
        png.unlink()
    cap = Capture.open(root)  # lazy: only the split files are parsed
    assert len(cap.frames()) == 6 and cap.cached_bytes == 0
    with pytest.raises(CaptureError, match="file_path"):
        cap.load_image(cap.frames()[0])


def test_interrupted_writer_leaves_no_split_files(tmp_path):
    root = tmp_path / "cap"
    cam = _cameras()[0]
    with pytest.raises(RuntimeError):
        with CaptureWriter(root) as writer:
            writer.write_flame_params(0, _params(np.random.default_rng(0)))
            writer.add_frame(0, cam, np.zeros((H, W, 3)), np.ones((H, W)), split="train")
            raise RuntimeError("generator crashed")
    assert not list(root.glob("transforms*.json"))
    with pytest.raises(CaptureError, match="transforms_train.json"):
        Capture.open(root)


def test_writer_refuses_inconsistent_input(tmp_path):
    cam = _cameras()[0]
    writer = CaptureWriter(tmp_path / "cap")
    with pytest.raises(CaptureError, match="do not match"):
        writer.add_frame(0, cam, np.zeros((H + 1, W, 3)), np.ones((H, W)), split="train")
    with pytest.raises(CaptureError, match="split"):
        writer.add_frame(0, cam, np.zeros((H, W, 3)), np.ones((H, W)), split="holdout")
    writer.add_frame(0, cam, np.zeros((H, W, 3)), np.ones((H, W)), split="train")
    with pytest.raises(CaptureError, match="twice"):
        writer.add_frame(0, cam, np.zeros((H, W, 3)), np.ones((H, W)), split="val")
    with pytest.raises(CaptureError, match="FLAME"):
        writer.finish()
    with pytest.raises(CaptureError, match="jaw_pose"):
        writer.write_flame_params(0, {**_params(np.random.default_rng(0)), "jaw_pose": np.zeros(2, np.float32)})


def test_record_frame_for_files_written_elsewhere(tmp_path):
    root = tmp_path / "cap"
    cam = _cameras()[1]
    writer = CaptureWriter(root)
    writer.write_flame_params(4, _params(np.random.default_rng(0)))
    with pytest.raises(CaptureError, match="not found"):
        writer.record_frame(4, cam, split="train", camera_index=3)
    write_png(root / "images/00004_03.png", np.zeros((H, W, 3)))
    write_png(root / "fg_masks/00004_03.png", np.ones((H, W)))
    frame = writer.record_frame(4, cam, split="train", camera_index=3)
    assert frame["file_path"] == "images/00004_03.png"
    writer.finish()
    assert validate_capture(root).views == 1
