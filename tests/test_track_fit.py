"""The monocular fit: FLAME and the camera back from a clip's 2D landmarks (synthetic, known answers)."""

import numpy as np
import pytest
import torch

from mogaface.core.errors import InputError
from mogaface.core.flame.landmarks import STATIC_IBUG, procedural_embedding
from mogaface.core.flame.model import FlameModel
from mogaface.core.track.fit import FitSettings, Observations, _bending, _knots, _spread, fit_landmarks, start_camera
from mogaface.core.track.head import LandmarkHead
from mogaface.core.track.photometric import vertex_embedding

FRAMES, WIDTH, HEIGHT, FOCAL = 12, 360, 640, 480.0


@pytest.fixture(scope="module")
def clip(procedural_head_pkl):
    """A turning, talking head's landmarks seen by a fixed camera, with half a pixel of noise."""
    model = FlameModel.load(procedural_head_pkl, dtype=torch.float64)
    embedding = procedural_embedding().subset(STATIC_IBUG)
    rng = np.random.default_rng(0)
    time = np.linspace(0, 1, FRAMES)[:, None]
    truth = {"shape": rng.normal(0, 0.8, (1, model.n_shape)),
             "expr": 0.8 * np.sin(2 * np.pi * time * rng.uniform(0.5, 1.5, model.n_expr)) * (np.arange(model.n_expr) < 6),
             "rotation": np.concatenate([0.15 * np.sin(3 * time), 0.5 * np.sin(2 * np.pi * time), 0 * time], 1),
             "jaw_pose": np.concatenate([0.15 * (1 + np.sin(7 * time)), 0 * time, 0 * time], 1),
             "translation": np.concatenate([0.01 * time, -0.01 * time, 0.02 * np.sin(4 * time)], 1)}
    with torch.no_grad():
        vertices = model(**{k: torch.as_tensor(v) for k, v in truth.items()}).numpy()
    camera = start_camera(WIDTH, HEIGHT, FOCAL)
    points = np.stack([camera.project(embedding.positions(v, model.faces.numpy()))[0] for v in vertices])
    points += rng.normal(0, 0.5, points.shape)
    confidence = np.ones(points.shape[:2])
    confidence[5, :] = 0  # a frame where the face was lost
    return model, Observations(points, confidence, WIDTH, HEIGHT, embedding), truth, vertices


def test_the_landmark_head_poses_as_the_whole_model(clip):
    model, obs, truth, vertices = clip
    head = LandmarkHead(model, obs.embedding)
    t = {k: torch.as_tensor(v) for k, v in truth.items()}
    landmarks = head(t["shape"], t["expr"], t["rotation"], t["jaw_pose"], t["translation"])
    expected = np.stack([obs.embedding.positions(v, model.faces.numpy()) for v in vertices])
    assert np.abs(landmarks.detach().numpy() - expected).max() < 1e-9
    # as the fit poses them, in single precision from double parameters: within a micrometre
    single = LandmarkHead(model, obs.embedding, dtype=torch.float32)(
        t["shape"], t["expr"], t["rotation"], t["jaw_pose"], t["translation"])
    assert single.dtype == torch.float32 and 0 < np.abs(single.detach().numpy() - expected).max() < 1e-6
    # and in a camera's frame, its motion folded into the head's: as if moved after
    camera = start_camera(WIDTH, HEIGHT, FOCAL)
    turn, move = torch.as_tensor(camera.w2c[:3, :3]), torch.as_tensor(camera.w2c[:3, 3])
    seen = head(t["shape"], t["expr"], t["rotation"], t["jaw_pose"], t["translation"], view=(turn, move))
    assert np.abs(seen.detach().numpy() - (expected @ camera.w2c[:3, :3].T + camera.w2c[:3, 3])).max() < 1e-9
    # every vertex, the eyes turned too: the jaw and the eyeballs move theirs about their joints
    everything = LandmarkHead(model, vertex_embedding(model.faces.numpy(), np.arange(len(model.v_template))))
    t["eyes_pose"] = torch.as_tensor(np.random.default_rng(1).normal(0, 0.2, (FRAMES, 6)))
    posed = everything(t["shape"], t["expr"], t["rotation"], t["jaw_pose"], t["translation"], t["eyes_pose"])
    with torch.no_grad():
        assert torch.abs(posed - model(**t)).max() < 1e-9


def test_a_clip_is_fitted_to_its_landmarks_and_the_mesh_follows(clip):
    model, obs, truth, vertices = clip
    fit = fit_landmarks(model, obs, FitSettings(steps=150, focal=FOCAL))  # a lens from the file's metadata
    seen = fit.seen
    assert not seen[5] and seen.sum() == FRAMES - 1
    assert fit.reprojection_px[seen].mean() < 1.2  # the noise: 0.5 px per axis, 0.7 px at the truth
    params = {k: torch.as_tensor(v if k != "shape" else v[None]) for k, v in fit.params.items()}
    with torch.no_grad():
        fitted = model(**params).numpy()
    # the head's rigid motion is recovered: the face's centre within a few mm of the truth, every frame
    face = np.unique(model.faces.numpy()[obs.embedding.faces])
    error_mm = 1000 * np.linalg.norm(fitted[:, face].mean(1) - vertices[:, face].mean(1), axis=1)
    assert np.median(error_mm[seen]) < 15, error_mm
    yaw = fit.params["rotation"][:, 1]
    assert np.corrcoef(yaw[seen], truth["rotation"][seen, 1])[0, 1] > 0.98
    jaw = fit.params["jaw_pose"][:, 0]
    assert np.corrcoef(jaw[seen], truth["jaw_pose"][seen, 0])[0, 1] > 0.8


def test_the_scoring_aligns_a_similar_copy_exactly_and_places_the_head(clip):
    """What bench track's errors stand on: the similarity alignment and the head's pose."""
    from scipy.spatial.transform import Rotation

    from mogaface.core.evaluate.track_error import head_to_world, similarity_aligned, vertices_and_joints

    model, _, truth, vertices = clip
    points = vertices[3]
    turn = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    copy = 1.3 * points @ turn.T + [0.1, -0.2, 0.5]
    assert np.abs(similarity_aligned(copy, points) - points).max() < 1e-9
    params = {k: np.asarray(v[3] if k != "shape" else v[0], np.float64) for k, v in truth.items()}
    posed, joints = vertices_and_joints(model, params, posed=True)
    unposed, _ = vertices_and_joints(model, {**params, "rotation": 0 * params["rotation"],
                                             "translation": 0 * params["translation"]}, posed=True)
    head = head_to_world(params, joints)  # the unposed head carried by the head's pose is the posed head
    assert np.abs(unposed @ head[:3, :3].T + head[:3, 3] - posed).max() < 1e-9


def test_a_camera_moved_onto_a_similar_head_sees_it_as_the_camera_sees_the_true_one(clip):
    """What bench track_avatar's novel views stand on: the tracked head is a turned, shifted and
    larger copy of the true one; the moved camera puts each of its points on the pixel where the
    true camera puts the true point, in front of it; with scale 1 (the heads' poses alone) the centre
    is carried rigidly."""
    from scipy.spatial.transform import Rotation

    from mogaface.core.camera import Camera
    from mogaface.core.evaluate.track_error import camera_onto, similarity

    points = clip[3][5]
    turn = Rotation.from_rotvec([-0.3, 0.5, 0.2]).as_matrix()
    tracked = 1.04 * points @ turn.T + [0.05, 0.1, -0.3]
    camera = Camera.look_at(eye=[0.6, 0.1, 0.9], target=points.mean(0), fx=900.0, width=512, height=512)
    scale, rotation, offset = similarity(tracked, points)
    assert abs(scale - 1 / 1.04) < 1e-9
    moved = camera_onto(camera, scale, rotation, offset)
    pixels, depth = camera.project(points)
    moved_pixels, moved_depth = moved.project(tracked)
    assert np.abs(moved_pixels - pixels).max() < 1e-6
    assert np.all(moved_depth > 0) and np.allclose(moved_depth, depth * 1.04)
    assert np.allclose(scale * rotation @ moved.center + offset, camera.center)  # the centre carried back
    rigid = camera_onto(camera, 1.0, rotation, offset)  # the heads' poses alone: the centre carried rigidly
    assert np.allclose(rotation @ rigid.center + offset, camera.center)


def test_the_gaze_is_fitted_from_the_iris_centres(procedural_head_pkl):
    """Both eyes turned alike, seen through the dense embedding's iris centres (no noise): the gaze
    comes back. At a phone's distance a tenth of a radian moves an iris by about a pixel here, so
    the bar is on the gaze's course over the clip, not on each frame's angle."""
    from mogaface.core.track.fit import eyes_pose
    from mogaface.core.track.mediapipe_embedding import IRIS_CENTRES, model_mediapipe_embedding

    model = FlameModel.load(procedural_head_pkl, dtype=torch.float64)
    embedding = model_mediapipe_embedding(model.faces.numpy())
    assert set(IRIS_CENTRES) <= set(embedding.ibug.tolist())
    time = np.linspace(0, 1, 10)[:, None]
    gaze = np.concatenate([0.15 * np.sin(2 * np.pi * time), 0.3 * np.cos(2 * np.pi * time)], 1)
    truth = {"shape": np.random.default_rng(1).normal(0, 0.5, (1, model.n_shape)),
             "rotation": np.concatenate([0 * time, 0.3 * time, 0 * time], 1),
             "eyes_pose": eyes_pose(torch.as_tensor(gaze)).numpy()}
    with torch.no_grad():
        vertices = model(**{k: torch.as_tensor(v) for k, v in truth.items()}).numpy()
    camera = start_camera(WIDTH, HEIGHT, FOCAL)
    points = np.stack([camera.project(embedding.positions(v, model.faces.numpy()))[0] for v in vertices])
    obs = Observations(points, np.ones(points.shape[:2]), WIDTH, HEIGHT, embedding)
    fit = fit_landmarks(model, obs, FitSettings(steps=150, focal=FOCAL, shape_prior=0.01, gaze_prior=0.01))
    fitted = fit.params["eyes_pose"]
    assert np.allclose(fitted[:, :3], fitted[:, 3:]) and np.abs(fitted[:, 2]).max() == 0  # both eyes alike
    assert np.corrcoef(fitted[:, 1], gaze[:, 1])[0, 1] > 0.9  # the yaw's course
    assert np.abs(fitted[:, :2] - gaze).mean() < 0.1  # radians
    mesh_points = ~np.isin(embedding.ibug, IRIS_CENTRES)
    without = fit_landmarks(model, Observations(points[:, mesh_points], np.ones((10, mesh_points.sum())), WIDTH, HEIGHT,
                                                embedding.subset(embedding.ibug[mesh_points])), FitSettings(steps=5, focal=FOCAL))
    assert np.abs(without.params["eyes_pose"]).max() == 0  # no iris centres: the eyes stay at rest


def test_several_clips_are_fitted_with_a_lens_each(clip):
    """The same performance seen by two phones of other sizes and lenses: each clip's camera keeps
    its own size and focal length, and both clips' landmarks are fitted as well as one clip's."""
    model, obs, truth, vertices = clip
    other = start_camera(480, 480, 600.0)
    points = np.stack([other.project(obs.embedding.positions(v, model.faces.numpy()))[0] for v in vertices])
    points += np.random.default_rng(1).normal(0, 0.5, points.shape)
    sizes = np.array([[WIDTH, HEIGHT]] * FRAMES + [[480, 480]] * FRAMES)
    both = Observations(np.concatenate([obs.points, points]), np.concatenate([obs.confidence, np.ones(points.shape[:2])]),
                        WIDTH, HEIGHT, obs.embedding, sizes, np.repeat([0, 1], FRAMES))
    fit = fit_landmarks(model, both, FitSettings(steps=300, focal=(FOCAL, 600.0)))  # 150 do for one clip
    assert [(c.width, c.height, c.fx) for c in fit.cameras] == [(WIDTH, HEIGHT, pytest.approx(FOCAL)),
                                                                  (480, 480, pytest.approx(600.0))]
    assert fit.camera_of(FRAMES + 2, "cam01").fx == pytest.approx(600.0) and fit.camera_of(2).fx == pytest.approx(FOCAL)
    assert fit.reprojection_px[fit.seen].mean() < 1.2
    moved_mm = 1000 * np.linalg.norm(fit.params["translation"][FRAMES:] - fit.params["translation"][:FRAMES], axis=1)
    assert np.median(moved_mm[obs.confidence.any(1)]) < 10  # the same head at the same place (one lens: 0.1 m off)
    with pytest.raises(InputError, match="one focal length per clip"):
        fit_landmarks(model, both, FitSettings(steps=1, focal=(FOCAL,)))


def test_the_photometric_stages_knots_hold_each_clips_ends_and_the_frames_between_follow():
    clips = np.array([0] * 7 + [1] * 4)
    knots = _knots(clips, 3)
    assert knots.tolist() == [0, 3, 6, 7, 10]  # every third frame of each clip, and its last
    assert _knots(clips, 1).tolist() == list(range(11))
    knots = torch.as_tensor(knots)
    full = torch.zeros(11, 2, dtype=torch.float64)
    fitted = torch.tensor([[0, 0], [3, 0], [6, 1], [10, 5], [10, 8]], dtype=torch.float64)
    _spread(full, fitted, knots)
    assert torch.equal(full[knots], fitted)  # the knots land where they were fitted
    assert full[:7, 0].tolist() == list(range(7))  # between them, in proportion
    assert full[7:, 1].tolist() == [5, 6, 7, 8]  # the second clip follows its own knots only
    # The smoothness measured at the knots is the per-frame one of the path through them:
    clip_ids = torch.as_tensor(clips)
    path = torch.zeros(11, 2, dtype=torch.float64)
    _spread(path, torch.randn(5, 2, dtype=torch.float64), knots)
    assert torch.allclose(_bending(path[knots], knots, clip_ids), _bending(path, torch.arange(11), clip_ids))
    bent = path.clone()
    bent[2] += 0.1  # a frame off the path bends it: only the per-frame sum sees it
    assert _bending(bent, torch.arange(11), clip_ids) > _bending(path, torch.arange(11), clip_ids) + 1e-3
