"""2D landmarks: the head model's iBUG-68 embedding, landmark files in VHAP's layout (written here
the way VHAP's detector wrappers write them, not by our writer), the synthetic detector, and the
cameras solved from landmarks."""

import pickle

import numpy as np
import pytest
import torch

from mogaface.core.data.camera_file import read_cameras
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import CaptureSettings, make_capture
from mogaface.core.data.landmarks import landmark_files, read_landmark_file, read_landmarks, write_landmark_file
from mogaface.core.errors import InputError, UnsafePickleError
from mogaface.core.evaluate.camera_error import pose_error
from mogaface.core.flame.landmarks import IBUG_COUNT, STATIC_IBUG, procedural_embedding, read_embedding
from mogaface.core.flame.procedural_mesh import build_mesh
from mogaface.core.train.camera_refine import CameraOffsets
from mogaface.core.train.landmark_cameras import solve_cameras, training_cameras

EXACT = {f"{g}_{k}": 0.0 for g in ("expr", "pose", "translation") for k in ("noise", "bias")}


def _exact_capture(root, camera_noise):
    """Tracking without error, landmarks without detector noise: only the cameras can be off."""
    settings = CaptureSettings(views=6, timesteps=16, size=64, supersample=1, camera_noise=camera_noise,
                               landmark_noise=0.0, landmark_bias=0.0, **EXACT)
    return make_capture(root, settings, progress=False)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    return _exact_capture(tmp_path_factory.mktemp("landmark_calibrated"), 1.0)


# -- the embedding ------------------------------------------------------------------------------

def test_procedural_landmarks_sit_where_ibug_puts_them():
    mesh = build_mesh()
    points = procedural_embedding().positions(mesh.vertices, mesh.faces)
    assert points.shape == (IBUG_COUNT, 3)
    for left, right in ((0, 16), (17, 26), (21, 22), (36, 45), (39, 42), (31, 35), (48, 54)):
        assert points[left, 0] < 0 < points[right, 0]  # iBUG's first points are the subject's right (−x)
        np.testing.assert_allclose(points[left] * [-1, 1, 1], points[right], atol=1e-6)  # the head is symmetric
    assert np.argmax(points[:, 2]) == 30  # the nose tip is the most forward point
    assert np.argmin(points[:, 1]) == 8  # the chin the lowest
    eyes = points[36:48, 1].mean()
    assert points[17:27, 1].min() > eyes > points[27:36, 1].max() - 0.02 > points[48:68, 1].max()
    assert abs(points[39, 0]) < abs(points[36, 0])  # the inner eye corner nearer the midline


def _vhap_style_npy(path, faces, bary):
    """A dict saved as VHAP's ``landmark_embedding_with_eyes.npy`` is: numpy ``full_*`` arrays of 70
    points (68 + two eyes) and the dynamic contour as torch tensors."""
    np.save(path, {"full_lmk_faces_idx": faces[None], "full_lmk_bary_coords": bary[None],
                   "static_lmk_faces_idx": faces[17:], "static_lmk_bary_coords": bary[17:],
                   "dynamic_lmk_faces_idx": torch.zeros(79, 17, dtype=torch.long),
                   "dynamic_lmk_bary_coords": torch.zeros(79, 17, 3)}, allow_pickle=True)


def test_embedding_files_of_vhap_and_flame_are_read_safely(tmp_path):
    rng = np.random.default_rng(0)
    faces = rng.integers(0, 9000, 70)
    bary = rng.dirichlet(np.ones(3), 70)
    _vhap_style_npy(tmp_path / "vhap.npy", faces, bary)
    vhap = read_embedding(tmp_path / "vhap.npy")
    np.testing.assert_array_equal(vhap.faces, faces[:68])  # the two eye points after the 68 are dropped
    np.testing.assert_allclose(vhap.barycentric, bary[:68])
    np.testing.assert_array_equal(vhap.ibug, np.arange(68))

    with open(tmp_path / "flame_static_embedding.pkl", "wb") as handle:  # FLAME's: 51 points, iBUG 17-67
        pickle.dump({"lmk_face_idx": faces[:51].astype(np.uint32), "lmk_b_coords": bary[:51]}, handle, protocol=2)
    static = read_embedding(tmp_path / "flame_static_embedding.pkl")
    np.testing.assert_array_equal(static.ibug, STATIC_IBUG)
    np.testing.assert_array_equal(static.faces, faces[:51])

    np.savez(tmp_path / "own.npz", lmk_faces_idx=faces[:68], lmk_bary_coords=bary[:68])
    np.testing.assert_array_equal(read_embedding(tmp_path / "own.npz").faces, faces[:68])

    class Payload:
        def __reduce__(self):
            return (print, ("executed",))

    np.save(tmp_path / "evil.npy", {"full_lmk_faces_idx": Payload()}, allow_pickle=True)
    with pytest.raises(UnsafePickleError, match="builtins.print") as refused:
        read_embedding(tmp_path / "evil.npy")
    assert "evil.npy" in str(refused.value)  # the file as given (the pickle is read in place, after the header)
    (tmp_path / "cut.npy").write_bytes((tmp_path / "vhap.npy").read_bytes()[:-40])
    with pytest.raises(InputError, match="cut.npy.*not a readable pickle"):
        read_embedding(tmp_path / "cut.npy")
    np.savez(tmp_path / "other.npz", faces=faces)
    with pytest.raises(InputError, match="full_lmk_faces_idx"):
        read_embedding(tmp_path / "other.npz")


# -- landmark files -----------------------------------------------------------------------------

def _star_rows(points_px, width, height, missing=()):
    """Rows as VHAP's STAR wrapper writes them: x / w, y / h, confidence 1; a frame without a face is
    a row of −1 (float64, which turns the whole stack float64)."""
    rows = []
    for t, frame in enumerate(points_px):
        if t in missing:
            rows.append(np.full((68, 3), -1.0))
        else:
            rows.append(np.concatenate([frame / [width, height], np.ones((68, 1))], 1).astype(np.float32))
    points = np.stack(rows)
    boxes = np.stack([np.r_[p.min(0), p.max(0), 1.0] if t not in missing else np.full(5, -1.0)
                      for t, p in enumerate(points_px)])
    return {"bounding_box": boxes, "face_landmark_2d": points}


def test_vhap_landmark_folders_are_read(tmp_path):
    rng = np.random.default_rng(1)
    pixels = rng.uniform(0, 200, (5, 68, 2))
    (tmp_path / "multi" / "landmark2d" / "STAR").mkdir(parents=True)
    np.savez(tmp_path / "multi" / "landmark2d" / "STAR" / "222200037.npz", **_star_rows(pixels, 200, 300, missing={2}))
    files = landmark_files(tmp_path / "multi", ["222200037", "220700191"])
    assert list(files) == ["222200037"]
    read = read_landmark_file(files["222200037"], 200, 300, timesteps=4)
    assert read.shape == (4, 68, 3)
    np.testing.assert_allclose(read[[0, 1, 3], :, :2], pixels[[0, 1, 3]], atol=1e-3)
    np.testing.assert_array_equal(read[2, :, 2], 0.0)  # no face found: no weight
    np.testing.assert_array_equal(read[[0, 1, 3], :, 2], 1.0)

    (tmp_path / "mono" / "landmark2d").mkdir(parents=True)  # a monocular sequence: one file for its camera
    np.savez(tmp_path / "mono" / "landmark2d" / "STAR.npz", **_star_rows(pixels, 200, 300))
    assert list(landmark_files(tmp_path / "mono", ["0"])) == ["0"]
    assert landmark_files(tmp_path / "mono", ["0", "1"]) == {}

    with pytest.raises(InputError, match=r"face_landmark_2d.*5 rows for a capture of 9 timesteps"):
        read_landmark_file(files["222200037"], 200, 300, timesteps=9)
    np.savez(tmp_path / "bad.npz", face_landmark_2d=np.zeros((4, 51, 3)))
    with pytest.raises(InputError, match=r"bad.npz.*expected shape \(N, 68, 3\)"):
        read_landmark_file(tmp_path / "bad.npz", 200, 300, timesteps=4)
    np.savez(tmp_path / "nan.npz", face_landmark_2d=np.full((4, 68, 3), np.nan))
    with pytest.raises(InputError, match=r"nan.npz.*NaN"):
        read_landmark_file(tmp_path / "nan.npz", 200, 300, timesteps=4)
    np.savez(tmp_path / "pickled.npz", face_landmark_2d=np.array([{"x": 1}], dtype=object))
    with pytest.raises(InputError, match="pickled.npz"):
        read_landmark_file(tmp_path / "pickled.npz", 200, 300, timesteps=1)


def test_landmark_files_round_trip(tmp_path):
    rows = np.random.default_rng(2).uniform(0, 64, (3, 68, 3))
    rows[..., 2] = rows[..., 2] > 32
    path = write_landmark_file(tmp_path, "cam00", rows, 64, 48)
    assert path == tmp_path / "landmark2d" / "STAR" / "cam00.npz"
    with np.load(path) as raw:  # normalised as VHAP writes them
        assert raw["face_landmark_2d"].max() < 1.4 and raw["bounding_box"].shape == (3, 5)
    np.testing.assert_allclose(read_landmark_file(path, 64, 48, 3), rows, atol=1e-4)


def test_synthetic_detector_sees_the_true_mesh_through_the_true_cameras(calibrated):
    capture = Capture.open(calibrated)
    truth = read_cameras(calibrated / "cameras_gt.json")
    found = read_landmarks(calibrated, capture.cameras, len(capture.timesteps))
    assert sorted(found) == sorted(capture.cameras)
    from mogaface.core.flame.model import FlameModel

    model = FlameModel.load(calibrated / "head.pkl")
    stored = np.load(calibrated / "flame_param_gt" / "00005.npz")
    params = {k: torch.as_tensor(v if k == "static_offset" else v.reshape(1, -1)) for k, v in stored.items()}
    points = procedural_embedding().positions(model(**params)[0].double().numpy(), build_mesh().faces)
    for camera_id, rows in found.items():
        seen = rows[5, :, 2] > 0
        assert 10 < seen.sum() <= 68
        uv, _ = truth[camera_id].project(points)
        np.testing.assert_allclose(rows[5, seen, :2], uv[seen], atol=2e-3)


# -- cameras from landmarks ---------------------------------------------------------------------

def _mean_rotation_error(cameras, truth):
    return float(np.mean([pose_error(cameras[c], truth[c])[0] for c in cameras]))


def test_landmarks_turn_miscalibrated_cameras_toward_the_truth(calibrated):
    capture = Capture.open(calibrated)
    truth = read_cameras(calibrated / "cameras_gt.json")
    before = _mean_rotation_error(training_cameras(capture), truth)
    result = solve_cameras(capture, calibrated / "head.pkl")
    after = _mean_rotation_error(result.cameras, truth)
    assert before > 1.0 and after < 0.5 * before  # the centres stay off by the calibration's ~9 mm
    assert all(row["rms_after_px"] < 0.25 * row["rms_before_px"] for row in result.report.values())
    offsets = CameraOffsets(training_cameras(capture))
    offsets.start_from(result.cameras)  # a valid refinement start: same intrinsics, same image size


def test_right_cameras_stay_and_the_command_writes_a_start(tmp_path, capsys):
    from mogaface.core.cli import main

    root = _exact_capture(tmp_path / "right", 0.0)
    assert main(["solve-cameras", str(root), "--out", str(tmp_path / "cams.json")]) == 0
    solved = read_cameras(tmp_path / "cams.json")
    truth = read_cameras(root / "cameras_gt.json")
    assert sorted(solved) == sorted(training_cameras(Capture.open(root)))
    assert _mean_rotation_error(solved, truth) < 0.01
    assert "wrote 5 cameras" in capsys.readouterr().out

    (root / "landmark2d" / "STAR").rename(root / "elsewhere")
    assert main(["solve-cameras", str(root), "--out", str(tmp_path / "none.json")]) != 0
    assert "no landmark file for any training camera" in capsys.readouterr().err
    assert not (tmp_path / "none.json").exists()


def _turned(w2c, rotvec):
    """The camera turned by ``rotvec`` (world axes) about its own centre."""
    from scipy.spatial.transform import Rotation

    c2w = np.linalg.inv(w2c)
    c2w[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix() @ c2w[:3, :3]
    return np.linalg.inv(c2w)


class _VhapScene:
    """The synthetic FLAME of ``vhap_fixture``, a 4-camera rig, a calibration turned by a degree per
    camera, and a landmark embedding written as VHAP's ``.npy`` (70 points on the face)."""

    def __init__(self, root, size=48, seed=4):
        import vhap_fixture as V

        from mogaface.core.flame.model import FlameModel
        from mogaface.core.flame.model_file import write_model_file

        self.size = size
        self.head = root / "head.npz"
        write_model_file(self.head, V.synthetic_flame_topology())
        self.flame = FlameModel.load(self.head, n_vertices=5143)
        rng = np.random.default_rng(seed)
        self.true = V.rig(4, size)
        self.calibrated = [dict(cam, w2c=_turned(cam["w2c"], rng.normal(scale=np.radians(1.0), size=3)))
                           for cam in self.true]
        self.faces = self.flame.faces.numpy()[: V.synthetic_flame_topology()["f"].shape[0]]
        rest = V.synthetic_flame_topology()["v_template"]
        front = np.where(rest[self.faces].mean(1)[:, 2] > 0.06)[0]
        self.chosen = rng.choice(front, 70, replace=False)
        self.bary = rng.dirichlet(np.ones(3) * 4, 70)
        self.embedding_file = root / "landmark_embedding_with_eyes.npy"
        _vhap_style_npy(self.embedding_file, self.chosen, self.bary)

    def export(self, folder, tracked, missing=()):
        """A sequence exported by VHAP with the turned calibration, and STAR's landmarks of the
        true views in its ``landmark2d/``."""
        import vhap_fixture as V

        folder = V.export_sequence(folder, self.flame, tracked, self.calibrated, self.size)
        steps = len(tracked["expr"])
        with torch.no_grad():
            posed = self.flame(**{k: torch.as_tensor(v if k != "shape" else v[None].repeat(steps, 0))
                                  for k, v in tracked.items() if k != "static_offset"},
                               static_offset=torch.as_tensor(tracked["static_offset"])).double().numpy()
        points = np.einsum("tlkc,lk->tlc", posed[:, self.faces[self.chosen[:68]]], self.bary[:68])
        (folder / "landmark2d" / "STAR").mkdir(parents=True)
        for cam in self.true:  # the detector sees the true views
            pixels = np.stack([V.project(p, cam)[0] for p in points])
            np.savez(folder / "landmark2d" / "STAR" / f"{cam['id']}.npz",
                     **_star_rows(pixels, self.size, self.size, missing=missing))
        return folder

    def check_turned_back(self, capture, result):
        """Each training camera's turn comes back to within 15 % of the calibration's error, and
        the landmarks are fitted exactly."""
        before = training_cameras(capture)
        assert sorted(result.cameras) == sorted(before) == sorted(cam["id"] for cam in self.true[:3])
        for cam in self.true[:3]:
            wrong = pose_error(before[cam["id"]], _as_camera(cam, before[cam["id"]]))[0]
            right = pose_error(result.cameras[cam["id"]], _as_camera(cam, before[cam["id"]]))[0]
            assert wrong > 0.5 and right < 0.15 * wrong, (cam["id"], wrong, right)
        assert all(row["rms_after_px"] < 0.01 < row["rms_before_px"] for row in result.report.values())


def test_cameras_of_a_vhap_export_are_turned_back_by_its_landmarks(tmp_path):
    """A sequence exported as VHAP exports it (OpenGL cameras, ``cy`` from the bottom, the 5143-vertex
    teeth, serial camera ids, the relocation by the mean translation) with a calibration turned by a
    degree per camera; landmarks as VHAP's STAR wrapper stores them, found on the true views; the
    embedding as VHAP's ``.npy``. With exact landmarks the views are fitted exactly and the turns
    come back to within what a shift of the head toward the cameras leaves free (perspective alone
    tells them apart on this narrow rig)."""
    import vhap_fixture as V

    scene = _VhapScene(tmp_path)
    tracked = V.tracking(scene.flame, 6, seed=0, translation=[0.0, 0.01, 0.0])
    folder = scene.export(tmp_path / "074_EMO-1_v16_DS4", tracked, missing={1})
    capture = Capture.open(folder)
    result = solve_cameras(capture, scene.head, read_embedding(scene.embedding_file),
                           points=np.arange(IBUG_COUNT), gauge="none")
    scene.check_turned_back(capture, result)


def test_a_union_of_sequences_takes_each_sequences_landmarks_and_its_shifted_cameras(tmp_path):
    """VHAP's union (``combine_nerf_datasets.py``): frames in the sibling sequence folders, timesteps
    numbered across them, each sequence's cameras shifted by its own mean translation. Each sequence
    keeps its own ``landmark2d/`` (rows of its own timesteps); the union reads them at its indices,
    and one turn per camera fits all its shifted poses."""
    import vhap_fixture as V

    from mogaface.core.data.landmarks import capture_landmarks
    from mogaface.core.data.validate import validate_capture

    scene = _VhapScene(tmp_path, seed=5)
    steps, subject = 5, V.tracking(scene.flame, 5, seed=0, translation=[0, 0, 0])
    sequences = [scene.export(tmp_path / f"306_SEQ-{i}_v16_DS4",
                              {**V.tracking(scene.flame, steps, seed=i, translation=[0.02 * i, 0.01, -0.015 * i]),
                               "shape": subject["shape"], "static_offset": subject["static_offset"]},
                              missing={2} if i == 1 else ())
                 for i in range(3)]
    union = V.combine(sequences, tmp_path / "UNION_306_3seq")
    capture = Capture.open(union)
    poses = {tuple(capture.camera(f).center.round(9)) for f in capture.frames("train") if f.camera_id == "220700191"}
    assert len(poses) == 2  # sequences 0 and 1 train; each has its own shift of the camera

    rows = capture_landmarks(capture, capture.cameras)
    file = read_landmark_file(sequences[1] / "landmark2d" / "STAR" / "220700191.npz", scene.size, scene.size, steps)
    assert np.array_equal(rows["220700191"][steps:2 * steps], file)  # sequence 1 is the union's timesteps 5–9
    assert rows["220700191"][steps + 2, :, 2].max() == 0  # its frame without a face stays unused
    assert validate_capture(union).landmark_cameras == sorted(capture.cameras)

    result = solve_cameras(capture, scene.head, read_embedding(scene.embedding_file),
                           points=np.arange(IBUG_COUNT), gauge="none")
    scene.check_turned_back(capture, result)

    # One command: the run solves its start, taking the embedding file that lies beside the FLAME model.
    from mogaface.core.cli import main

    run = tmp_path / "run"
    assert main(["train", str(union), "--out", str(run), "--head", str(scene.head), "--preset", "quick",
                 "--steps", "2", "--quiet", "--refine-cameras", "1", "--cameras-start", "landmarks"]) == 0
    direct = solve_cameras(capture, scene.head).cameras
    started = read_cameras(run / "cameras_landmarks.json")
    assert max(pose_error(started[c], direct[c])[0] for c in direct) < 1e-3
    assert max(pose_error(direct[c], result.cameras[c])[0] for c in direct) > 0.01  # a gauge and 51 points apart


def test_a_monocular_export_keeps_its_camera(tmp_path):
    """VHAP's monocular export, its landmarks in ``landmark2d/STAR.npz``. One camera's turn is a rigid
    motion of every head, which the adjustment corrects per timestep anyway: any turn fits the
    landmarks exactly, so none is made (a free solve turned this camera by 1.5°, fitting to 1e-6 px)."""
    import vhap_fixture as V

    scene = _VhapScene(tmp_path)
    scene.true, scene.calibrated = scene.true[:1], scene.calibrated[:1]
    folder = scene.export(tmp_path / "mono", V.tracking(scene.flame, 6, seed=0, translation=[0.0, 0.01, 0.0]))
    (folder / "landmark2d" / "STAR" / f"{scene.true[0]['id']}.npz").rename(folder / "landmark2d" / "STAR.npz")
    capture = Capture.open(folder)
    result = solve_cameras(capture, scene.head)
    (camera_id, row), = result.report.items()
    assert row["landmarks"] > 100 and "only camera" in row["kept"] and row["rotation_deg"] == 0.0
    assert np.allclose(result.cameras[camera_id].w2c, training_cameras(capture)[camera_id].w2c, atol=1e-6)


def test_a_flame_model_takes_its_embedding_from_beside_it_or_from_the_option(tmp_path):
    import vhap_fixture as V

    from mogaface.core.cli import main

    scene = _VhapScene(tmp_path)
    folder = scene.export(tmp_path / "seq", V.tracking(scene.flame, 4, seed=0, translation=[0.0, 0.01, 0.0]))
    capture = Capture.open(folder)
    beside = solve_cameras(capture, scene.head).cameras  # landmark_embedding_with_eyes.npy lies beside head.npz
    moved = tmp_path / "elsewhere" / "embedding.npy"
    moved.parent.mkdir()
    scene.embedding_file.rename(moved)
    with pytest.raises(InputError, match="beside the model as landmark_embedding_with_eyes.npy"):
        solve_cameras(capture, scene.head)
    run = tmp_path / "run"
    assert main(["train", str(folder), "--out", str(run), "--head", str(scene.head), "--preset", "quick",
                 "--steps", "1", "--quiet", "--cameras-start", "landmarks", "--landmark-embedding", str(moved)]) == 0
    started = read_cameras(run / "cameras_landmarks.json")
    assert max(pose_error(started[c], beside[c])[0] for c in beside) < 1e-3


def _as_camera(cam, like):
    """The fixture's true OpenCV camera as the capture's ``Camera`` (the relocation only shifts
    centres; rotations compare as they are)."""
    import dataclasses

    w2c = like.w2c.copy()
    w2c[:3, :3] = cam["w2c"][:3, :3]
    return dataclasses.replace(like, w2c=w2c)


def test_training_starts_its_refinement_from_solved_cameras(calibrated, tmp_path):
    from mogaface.core.cli import main

    assert main(["solve-cameras", str(calibrated), "--out", str(tmp_path / "cams.json")]) == 0
    run = tmp_path / "run"
    assert main(["train", str(calibrated), "--out", str(run), "--preset", "quick", "--steps", "2", "--quiet",
                 "--cameras-start", str(tmp_path / "cams.json")]) == 0
    solved, refined = read_cameras(tmp_path / "cams.json"), read_cameras(run / "cameras_refined.json")
    calibration = training_cameras(Capture.open(calibrated))
    moved = np.mean([pose_error(refined[c], solved[c])[0] for c in solved])  # a step or two of Adam
    away = np.mean([pose_error(calibration[c], solved[c])[0] for c in solved])
    assert moved < 0.1 * away, (moved, away)


def test_a_refining_run_can_solve_its_start_from_the_landmarks(calibrated, tmp_path):
    from mogaface.core.cli import main

    run = tmp_path / "run"
    assert main(["train", str(calibrated), "--out", str(run), "--preset", "quick", "--steps", "2", "--quiet",
                 "--refine-cameras", "2", "--cameras-start", "landmarks"]) == 0
    first = run / "camera_rounds" / "1"
    assert (first / "cameras_landmarks.json").exists()  # the first round solved them; the last starts from it
    assert not (run / "cameras_landmarks.json").exists()
    direct = solve_cameras(Capture.open(calibrated), calibrated / "head.pkl").cameras
    solved = read_cameras(first / "cameras_landmarks.json")
    assert max(pose_error(solved[c], direct[c])[0] for c in direct) < 1e-3
    (calibrated / "landmark2d").rename(tmp_path / "away")  # a resumed run does not solve them again
    try:
        assert main(["train", str(calibrated), "--out", str(run), "--resume", "--steps", "3", "--quiet"]) == 0
    finally:
        (tmp_path / "away").rename(calibrated / "landmark2d")


def test_measured_centres_hold_the_rig_from_the_solve_through_refinement(calibrated, tmp_path):
    """``--camera-gauge none`` (a rig whose centres are measured): the solve and the refinement turn
    each camera about its calibrated centre and move no centre; the rigid gauge moves them all."""
    from mogaface.core.cli import main

    run = tmp_path / "run"
    assert main(["train", str(calibrated), "--out", str(run), "--preset", "quick", "--steps", "2", "--quiet",
                 "--refine-cameras", "1", "--cameras-start", "landmarks", "--camera-gauge", "none"]) == 0
    calibration = training_cameras(Capture.open(calibrated))
    solved, refined = read_cameras(run / "cameras_landmarks.json"), read_cameras(run / "cameras_refined.json")
    for cameras in (solved, refined):
        assert max(np.abs(cameras[c].center - calibration[c].center).max() for c in calibration) < 1e-6
        assert min(pose_error(cameras[c], calibration[c])[0] for c in calibration) > 0.01  # every one turned
    rigid = solve_cameras(Capture.open(calibrated), calibrated / "head.pkl").cameras
    assert max(np.abs(rigid[c].center - calibration[c].center).max() for c in calibration) > 1e-4
