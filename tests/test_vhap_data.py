"""Captures as VHAP writes them (tests/vhap_fixture.py, not our writer), trained, rendered, checked.

The head is a SYNTHETIC model of FLAME's size (5023 vertices, FLAME's joints, random bases);
its tracking carries VHAP's 5143-vertex offsets, so the teeth extension is exercised.
"""

import json
import os

import numpy as np
import pytest
import torch
import vhap_fixture as V

from mogaface.core.avatar.avatar import Avatar, flame_params_to_torch, render_frame
from mogaface.core.data.capture import Capture
from mogaface.core.data.cy_check import check_cy, judge
from mogaface.core.data.validate import validate_capture
from mogaface.core.errors import CaptureError
from mogaface.core.evaluate.evaluation import evaluate_run
from mogaface.core.flame.model import FlameModel
from mogaface.core.flame.model_file import write_model_file
from mogaface.core.flame.teeth import LIP_RING_LOWER, LIP_RING_UPPER, teeth_faces
from mogaface.core.train import config as C
from mogaface.core.train.trainer import Trainer

SIZE = 32


@pytest.fixture(scope="session")
def head(tmp_path_factory):
    path = tmp_path_factory.mktemp("synthetic_flame") / "head.npz"
    write_model_file(path, V.synthetic_flame_topology())
    return path


@pytest.fixture(scope="session")
def flame(head):
    return FlameModel.load(head, n_vertices=5143)


@pytest.fixture(scope="session")
def data(tmp_path_factory, flame):
    """Three sequences of one subject, their union, a monocular export and a dynamic-offset one."""
    root = tmp_path_factory.mktemp("vhap")
    cameras = V.rig(3, SIZE)
    sequences = []
    for i in range(3):
        tracked = V.tracking(flame, 4, seed=i, translation=[0.02 * i, 0.01, -0.015 * i])
        sequences.append(V.export_sequence(root / f"306_SEQ-{i}_v16_DS4", flame, tracked, cameras, SIZE))
    union = V.combine(sequences, root / "UNION_306_3seq")
    mono = V.export_sequence(root / "mono", flame, V.tracking(flame, 4, seed=7, translation=[0, 0, 0]),
                             V.rig(1, SIZE), SIZE)
    dynamic = V.export_sequence(root / "dynamic", flame,
                                V.tracking(flame, 4, seed=9, translation=[0, 0, 0], dynamic=True), cameras, SIZE)
    return {"root": root, "sequences": sequences, "union": union, "mono": mono, "dynamic": dynamic}


def tiny_config(steps=3):
    return C.resolve(overrides={
        "train": {"steps": steps, "threads": 1, "log_every": 1, "checkpoint_every": 100},
        "densify": {"start": 100, "stop": 200, "interval": 50, "opacity_reset_interval": 0},
        "eval": {"at_end": False, "lpips": False},
    })


def train_and_render(capture_root, head, out):
    """A few training steps, then one render of the first training frame: finite and not blank."""
    result = Trainer(capture_root, out, tiny_config(), head_file=head).run()
    assert result["complete"]
    avatar = Avatar.load(out / "avatar.pt")
    assert avatar.flame.n_vertices == 5143 and len(avatar.flame.faces) == V.synthetic_flame_topology()["f"].shape[0] + 168
    cap = Capture.open(capture_root)
    frame = cap.frames("train")[0]
    rgb, alpha = render_frame(avatar, cap.flame_params(frame.timestep_index), cap.camera(frame), (1.0, 1.0, 1.0))
    assert rgb.shape == (SIZE, SIZE, 3) and np.isfinite(rgb).all() and alpha.max() > 0.5
    return avatar


# -- union datasets ------------------------------------------------------------------------------
def test_union_of_three_sequences_loads_with_cameras_per_sequence(data, flame):
    union = data["union"]
    frame0 = json.loads((union / "transforms_train.json").read_text())["frames"][0]
    assert frame0["file_path"].startswith("../306_SEQ-0_v16_DS4/")  # as combine_nerf_datasets.py writes it
    summary = validate_capture(union)
    assert summary.views == 3 and summary.timesteps == 12
    assert summary.flame_sizes["static_offset"] == (5143, 3)
    cap = Capture.open(union)
    assert set(cap.splits) == {"train", "val", "test"}
    # Each frame belongs to the sequence folder its image lies in: a timestep's neighbours (camera
    # delays) stay inside its sequence.
    assert cap.sequences == {f"306_SEQ-{i}_v16_DS4": [4 * i + k for k in range(4)] for i in range(3)}
    from mogaface.core.train.camera_delays import CameraDelays

    neighbours = CameraDelays(cap.cameras, cap.timesteps, cap.sequences).neighbours
    assert neighbours[3] == (2, 3) and neighbours[4] == (4, 5)
    cam_id = cap.frames("train")[0].camera_id
    first = cap.camera_at(cam_id, 0).w2c
    second = cap.camera_at(cam_id, 4).w2c  # same camera, next sequence: moved by its own mean translation
    assert not np.allclose(first, second)
    assert np.allclose(first[:3, :3], second[:3, :3])
    # The pose per frame is what VHAP wrote for that sequence: FLAME's translation + camera move agree.
    for t in (0, 5, 9):
        frame = next(f for f in cap.frames() if f.timestep_index == t)
        mask = cap.load_image(frame)[1]
        camera = cap.camera(frame)
        mesh, _ = V.rasterize(posed(flame, cap, t), flame.faces.numpy(), {"K": camera.K, "w2c": camera.w2c}, SIZE)
        assert (mesh == (mask > 0.5)).mean() > 0.98


def posed(flame, cap, t):
    """The tracked mesh of timestep ``t`` (float64 numpy)."""
    with torch.no_grad():
        return flame(**flame_params_to_torch(cap.flame_params(t)))[0].double().numpy()


def test_union_trains_and_renders(data, head, tmp_path):
    train_and_render(data["union"], head, tmp_path / "run")


def test_paths_leaving_the_union_root_are_refused(data, tmp_path):
    import shutil

    union = tmp_path / "u" / "UNION"
    shutil.copytree(data["union"], union)
    for seq in data["sequences"]:
        shutil.copytree(seq, tmp_path / "u" / seq.name)
    Capture.open(union)
    doc = json.loads((union / "transforms_train.json").read_text())
    for bad in ("../../306_SEQ-0_v16_DS4/images/00000_00.png", "../306_SEQ-0_v16_DS4/../../x.png", "..", "../x.png",
                "/tmp/x.png"):
        doc["frames"][1]["file_path"] = bad
        (union / "transforms_train.json").write_text(json.dumps(doc))
        with pytest.raises(CaptureError) as info:
            Capture.open(union)
        assert "transforms_train.json" in str(info.value) and "frames[1].file_path" in str(info.value)


def test_symlinks_out_of_the_tree_are_refused_inside_allowed(data, tmp_path):
    import shutil

    parent = tmp_path / "u"
    union = parent / "UNION"
    shutil.copytree(data["union"], union)
    outside = tmp_path / "elsewhere"
    for seq in data["sequences"]:
        shutil.copytree(seq, parent / seq.name)
    # Inside the tree: a sequence's images folder linked to a copy kept in the same parent.
    seq0 = parent / data["sequences"][0].name
    shutil.move(seq0 / "images", parent / "images_store")
    os.symlink(parent / "images_store", seq0 / "images")
    validate_capture(union)
    # Out of the tree: the same folder moved outside the parent and linked.
    os.unlink(seq0 / "images")
    shutil.move(parent / "images_store", outside)
    os.symlink(outside, seq0 / "images")
    with pytest.raises(CaptureError) as info:
        validate_capture(union)
    assert "file_path" in str(info.value) and "symbolic link" in str(info.value)
    # A single file linked out is refused the same way (canonical file of the union itself).
    os.unlink(seq0 / "images")
    shutil.move(outside, seq0 / "images")
    validate_capture(union)
    (tmp_path / "canon.npz").write_bytes((union / "canonical_flame_param.npz").read_bytes())
    (union / "canonical_flame_param.npz").unlink()
    os.symlink(tmp_path / "canon.npz", union / "canonical_flame_param.npz")
    with pytest.raises(CaptureError, match="symbolic link"):
        validate_capture(union)


# -- cy ------------------------------------------------------------------------------------------
def test_bottom_origin_cy_projects_the_tracked_mesh_into_the_masks(data, head, flame, tmp_path):
    seq = data["sequences"][0]
    frame_json = json.loads((seq / "transforms_train.json").read_text())["frames"][0]
    cap = Capture.open(seq)
    frame = next(f for f in cap.frames("train") if f.camera_index == frame_json["camera_index"]
                 and f.timestep_index == frame_json["timestep_index"])
    camera = cap.camera(frame)
    assert camera.cy == pytest.approx(SIZE - frame_json["cy"])  # the file's cy is from the bottom edge
    mask = cap.load_image(frame)[1] > 0.5
    rows = np.flatnonzero(mask.any(1))
    for reading, expect_close in ((camera.K, True), (None, False)):
        K = camera.K.copy()
        if reading is None:
            K[1, 2] = SIZE - K[1, 2]  # the mirrored (top-origin) reading
        silhouette, _ = V.rasterize(posed(flame, cap, frame.timestep_index), flame.faces.numpy(),
                                    {"K": K, "w2c": camera.w2c}, SIZE)
        mesh_rows = np.flatnonzero(silhouette.any(1))
        error = max(abs(mesh_rows[0] - rows[0]), abs(mesh_rows[-1] - rows[-1]))
        assert (error <= 1) == expect_close, (reading is None, error)
    report = check_cy(cap, head)
    assert report.verdict == "confirmed" and report.coverage[0] > report.coverage[1]
    # Declared top while the data are bottom-origin: the check says the files are mirrored.
    for name in ("train", "val", "test"):
        path = seq / f"transforms_{name}.json"
        doc = json.loads(path.read_text())
        path.write_text(json.dumps({**doc, "cy_origin": "top"}))
    try:
        report = check_cy(Capture.open(seq), head)
        assert report.verdict == "mirrored" and "cy_origin" in report.reason
        # Training such a folder says so at its start (a warning event), and goes on.
        trainer = Trainer(seq, tmp_path / "run", tiny_config(), head_file=head)
        trainer.events.close()
        warnings = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
        assert any(e["event"] == "warning" and "mirrored" in e["message"] for e in warnings), warnings
    finally:
        for name in ("train", "val", "test"):
            path = seq / f"transforms_{name}.json"
            doc = json.loads(path.read_text())
            doc.pop("cy_origin")
            path.write_text(json.dumps(doc))


def test_the_cy_verdict_needs_a_difference_that_stands_out_of_its_spread():
    steady = judge("bottom", [0.95, 0.96, 0.94, 0.95], [0.93, 0.94, 0.92, 0.935])
    assert steady.verdict == "confirmed"
    assert judge("top", [0.93, 0.94, 0.92, 0.935], [0.95, 0.96, 0.94, 0.95]).verdict == "mirrored"
    # A calibration a degree off: frames disagree by more than their mean difference (what
    # four frames of the 128² camera-noise capture once read as "mirrored").
    scattered = judge("bottom", [0.80, 0.78, 0.83, 0.75, 0.82, 0.79], [0.814, 0.773, 0.837, 0.727, 0.844, 0.80])
    assert scattered.verdict == "undecided" and "spread" in scattered.reason
    assert judge("bottom", [0.9, 0.9], [0.899, 0.899]).verdict == "undecided"  # below the margin


# -- monocular -----------------------------------------------------------------------------------
def test_monocular_export_trains_and_evaluation_names_what_it_cannot_run(data, head, tmp_path):
    mono = data["mono"]
    assert json.loads((mono / "transforms_val.json").read_text())["frames"] == []
    cap = Capture.open(mono)
    assert "val" not in cap.splits and "monocular" in cap.empty_splits["val"]
    train_and_render(mono, head, tmp_path / "run")
    result = evaluate_run(tmp_path / "run", lpips=False, comparisons=0)
    assert "novel_view" not in result["protocols"] and "self_reenactment" in result["protocols"]
    assert "val split is empty" in result["skipped"]["novel_view"]
    assert "not run" in (tmp_path / "run" / "metrics.md").read_text()


# -- dynamic offsets -----------------------------------------------------------------------------
def test_dynamic_offsets_are_applied(data, head, flame, tmp_path):
    cap = Capture.open(data["dynamic"])
    params = cap.flame_params(2)
    assert params["dynamic_offset"].shape == (5143, 3)
    raw = np.load(data["dynamic"] / "flame_param/00002.npz")
    with torch.no_grad():
        plain = {k: torch.as_tensor(np.asarray(v)) for k, v in raw.items() if k not in ("dynamic_offset", "static_offset")}
        plain["shape"] = plain["shape"][None]
        both = torch.as_tensor(raw["static_offset"] + raw["dynamic_offset"])
        expected = flame(**plain, static_offset=both)[0]
        got = flame(**flame_params_to_torch(params))[0]
        without = flame(**flame_params_to_torch({k: v for k, v in params.items() if k != "dynamic_offset"}))[0]
    assert torch.allclose(got, expected, atol=1e-6) and not torch.allclose(got, without, atol=1e-4)
    avatar = train_and_render(data["dynamic"], head, tmp_path / "run")
    saved = np.load(tmp_path / "run" / "flame_param" / "00002.npz")
    assert np.allclose(saved["dynamic_offset"][0], raw["dynamic_offset"][0])
    assert avatar.flame.n_vertices == 5143


# -- VHAP's mesh mode ----------------------------------------------------------------------------
def test_mesh_mode_export_gets_a_clear_message(data, tmp_path):
    import shutil

    seq = tmp_path / "mesh"
    shutil.copytree(data["sequences"][0], seq)
    path = seq / "transforms_train.json"
    doc = json.loads(path.read_text())
    for frame in doc["frames"]:
        frame.pop("flame_param_path")
        frame["mesh_path"] = f"meshes/{frame['timestep_index']:05d}.obj"
        frame["exp_path"] = f"flame/exp/{frame['timestep_index']:05d}.txt"
    path.write_text(json.dumps(doc))
    with pytest.raises(CaptureError, match="flame-mode param") as info:
        Capture.open(seq)
    assert "flame_param_path" in str(info.value)


# -- teeth ---------------------------------------------------------------------------------------
def test_teeth_follow_the_construction_vhap_and_gaussianavatars_use(flame):
    faces = teeth_faces()
    assert faces.shape == (168, 3) and faces.min() == 0 and faces.max() == 119
    # Face facts from VHAP's public add_teeth: first upper front, upper back, lower front, lower back.
    for index, face in ((0, [0, 31, 30]), (28, [60, 75, 76]), (56, [75, 30, 76]), (84, [45, 46, 15]),
                        (112, [90, 106, 105]), (140, [105, 106, 45])):
        assert faces[index].tolist() == face
    v = flame.v_template.double().numpy()
    teeth = v[5023:]
    lips_z = v[list(LIP_RING_UPPER) + list(LIP_RING_LOWER), 2].min()
    assert (teeth[:, 2] < lips_z).all()  # behind the lips
    assert teeth[:60, 1].max() > teeth[:60, 1].min()  # rows of different heights
    with torch.no_grad():
        rest = flame()[0]
        jaw = flame(jaw_pose=torch.tensor([[0.3, 0.0, 0.0]]))[0]
        neck = flame(neck_pose=torch.tensor([[0.2, 0.0, 0.0]]))[0]
    moved = (jaw - rest).norm(dim=1)[5023:]
    upper = np.repeat([1, 0, 1, 0, 1, 1, 0, 0], 15).astype(bool)
    assert moved[~upper].min() > 1e-3 and moved[upper].max() < 1e-9  # lower teeth on the jaw only
    assert (neck - rest).norm(dim=1)[5023:].min() > 1e-3  # all teeth follow the neck


def test_tracking_with_another_vertex_count_is_refused(head):
    from mogaface.core.errors import ModelFileError

    with pytest.raises(ModelFileError, match="5143"):
        FlameModel.load(head, n_vertices=5100)


# -- out to GaussianAvatars ----------------------------------------------------------------------
def test_binding_ply_writes_the_motion_file_gaussianavatars_opens(data, head, tmp_path):
    from mogaface.core.avatar.export import export_binding_ply

    cap = Capture.open(data["dynamic"])
    avatar = Avatar.initial(head, 0, n_vertices=5143)
    motion = {t: cap.flame_params(t) for t in cap.timesteps}
    written = export_binding_ply(avatar, tmp_path / "point_cloud.ply", motion[0], motion=motion)
    ga = np.load(tmp_path / "flame_param.npz")  # GaussianAvatars: Path(ply).parent / "flame_param.npz"
    assert tmp_path / "flame_param.npz" in written
    T = len(cap.timesteps)
    assert ga["shape"].shape == (300,) and ga["expr"].shape == (T, 100) and ga["eyes_pose"].shape == (T, 6)
    for key in ("rotation", "neck_pose", "jaw_pose", "translation"):
        assert ga[key].shape == (T, 3)
    assert ga["static_offset"].shape == (1, 5143, 3) and ga["dynamic_offset"].shape == (T, 5143, 3)
    assert np.allclose(ga["dynamic_offset"][1], motion[1]["dynamic_offset"])


def test_our_synthetic_capture_reads_as_gaussianavatars_reads_it(tmp_path):
    """GaussianAvatars' dataset reader, followed from its public code: all three split files,
    per frame ``file_path``/``transform_matrix``/``w``/``h``/``camera_angle_x``/``timestep_index``,
    and per timestep ``np.load(flame_param_path)`` whose ``static_offset`` its ``load_meshes`` indexes."""
    from mogaface.core.data.generator import CaptureSettings, make_capture

    root = tmp_path / "cap"
    make_capture(root, CaptureSettings(views=2, timesteps=16, size=32, supersample=1), progress=False)
    meshes = {}
    for split in ("train", "val", "test"):
        contents = json.loads((root / f"transforms_{split}.json").read_text())
        for frame in contents["frames"]:
            assert (root / frame["file_path"]).is_file()
            c2w = np.array(frame["transform_matrix"])
            assert c2w.shape == (4, 4) and frame["w"] == 32 and frame["h"] == 32 and 0 < frame["camera_angle_x"] < 3
            params = dict(np.load(root / frame["flame_param_path"], allow_pickle=False))
            meshes[frame["timestep_index"]] = params
    first = meshes[0]
    n_vertices = FlameModel.load(root / "head.pkl").n_vertices
    assert first["static_offset"].shape == (1, n_vertices, 3)  # meshes[0]['static_offset'] in load_meshes
    for key in ("expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation"):
        assert first[key].ndim == 2 and first[key].shape[0] == 1
    # Our reader gets the principal point back from VHAP's bottom-origin cy.
    cap = Capture.open(root)
    frame = json.loads((root / "transforms_train.json").read_text())["frames"][0]
    assert cap.cameras[frame["camera_id"]].cy == pytest.approx(32 - frame["cy"])


def test_blender_side_reads_teeth_tracking_and_union_cameras(data, head):
    from mogaface.core.for_blender.cameras import capture_scene
    from mogaface.core.for_blender.head_rig import head_import

    scene = capture_scene(data["union"])
    assert len(scene.cameras) == 3 and len(scene.moving_cameras) == 3
    single = capture_scene(data["sequences"][0])
    assert single.moving_cameras == []
    imported = head_import(head, shape_file=data["sequences"][0] / "flame_param" / "00000.npz")
    assert imported.basis.shape == (5143, 3) and imported.faces.max() == 5142


def test_check_capture_reports_the_cy_convention_and_empty_splits(data, head, capsys):
    from mogaface.core.cli import main

    assert main(["check-capture", str(data["union"]), "--head", str(head)]) == 0
    out = capsys.readouterr().out
    assert "cy: read from the bottom edge (VHAP's convention)" in out and "; confirmed" in out
    assert main(["check-capture", str(data["mono"])]) == 0
    out = capsys.readouterr().out
    assert "split val: empty (no camera is held out" in out and "unchecked (no head model" in out
