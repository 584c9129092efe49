"""Face detection, landmarks with irises and the person's mask (core/track/detect.py), offline.

On scikit-image's astronaut photograph (512×512, a real photograph shipped in a package). Her
iris centres were measured by hand: the photograph's eyes enlarged 24 times with a one-pixel grid,
each iris read as the span of its dark pixels (the image's left eye: columns 200–205, rows 97–102;
the other: columns 244–247, rows 100–104), the centre the middle of that span, in pixel units whose
pixel ``(i, j)`` covers ``[j, j+1) × [i, i+1)``. Reading the edges is good to about a pixel.
"""

import shutil

import numpy as np
import pytest
from skimage import data

from mogaface.core.errors import InputError
from mogaface.core.track import mediapipe_face as mf
from mogaface.core.track import models
from mogaface.core.track.detect import LANDMARK_COUNT, FaceTracker, draw_overlay, ibug68
from mogaface.core.track.mediapipe_ibug68 import IBUG68_FROM_MESH, derive

EYE_CENTRES = np.array([[203.0, 100.0], [246.0, 102.5]])  # hand-measured (see the module's docstring)


@pytest.fixture(scope="module")
def tracker():
    return FaceTracker(threads=2, track=False)


@pytest.fixture(scope="module")
def astronaut():
    return data.astronaut()


@pytest.fixture(scope="module")
def found(tracker, astronaut):
    return tracker(astronaut)


def test_the_astronaut_has_one_face_with_its_landmarks_in_its_box(found):
    assert found.faces == 1 and found.face is not None and not found.face.tracked
    face = found.face
    x1, y1, x2, y2 = face.box
    assert 170 < x1 < 190 and 75 < y1 < 95 and 265 < x2 < 285 and 170 < y2 < 190  # around her face
    assert face.score > 0.8 and face.presence > 0.9
    assert face.landmarks.shape == (LANDMARK_COUNT, 3) and np.all(np.isfinite(face.landmarks))
    # the detector's box is the face from brows to chin: the forehead's mesh points lie just above it
    centre, half = np.array([x1 + x2, y1 + y2]) / 2, np.array([x2 - x1, y2 - y1]) / 2
    assert np.all(np.abs(face.landmarks[:, :2] - centre) <= 1.25 * half)
    assert np.mean(np.all(np.abs(face.landmarks[:, :2] - centre) <= half, axis=1)) > 0.9
    assert face.confidence.shape == (LANDMARK_COUNT,) and face.ibug68().shape == (68, 3)


def test_the_irises_are_where_her_eyes_are(found):
    landmarks = found.face.landmarks
    centres = landmarks[[468, 473], :2]
    assert np.all(np.linalg.norm(centres - EYE_CENTRES, axis=1) < 1.5), centres
    for start, corners in zip((468, 473), mf.EYE_CORNERS):
        iris = landmarks[start:start + 5, :2]
        radius = np.linalg.norm(iris[1:] - iris[0], axis=1)
        assert np.all((radius > 2.0) & (radius < 6.0))  # her irises are about 7 px across
        right, top, left, bottom = iris[1:]
        assert right[0] > iris[0, 0] > left[0] and top[1] < iris[0, 1] < bottom[1]  # MediaPipe's order
        eye = landmarks[list(corners), :2]
        assert eye[:, 0].min() < iris[0, 0] < eye[:, 0].max()  # between the eye's corners


def test_the_mask_covers_her_and_not_the_background(found, astronaut):
    mask = found.mask
    assert mask.shape == astronaut.shape[:2] and mask.dtype == np.float32
    assert 0.0 <= mask.min() and mask.max() <= 1.0
    assert mask[130, 225] > 0.9 and mask[400, 250] > 0.9  # her face, her suit
    assert mask[:40, :40].max() < 0.1 and mask[:40, -40:].max() < 0.1  # the background's top corners


def test_a_blank_frame_has_no_face(tracker):
    for blank in (np.zeros((240, 320, 3), np.uint8), np.full((240, 320, 3), 0.5, np.float32)):
        result = tracker(blank)
        assert result.face is None and result.faces == 0 and result.detections.shape == (0, 5)


def test_two_faces_are_counted_and_the_largest_is_followed(tracker, astronaut):
    from skimage.transform import resize

    head = astronaut[20:276, 100:356]
    small = (resize(head, (192, 192), order=1, anti_aliasing=False) * 255).astype(np.uint8)  # the detector's
    frame = np.zeros((256, 464, 3), np.uint8)  # short range wants faces of at least about a fifth of the frame
    frame[:, :256] = head
    frame[32:224, 272:464] = small
    result = tracker(frame)
    assert result.faces == 2
    areas = np.prod(result.detections[:, 2:4] - result.detections[:, :2], axis=1)
    assert areas[0] == areas.max() and np.allclose(result.face.box, result.detections[0, :4])
    assert result.face.box[2] < 256  # the face on the left, the larger one


def test_the_next_frame_is_tracked_and_a_lost_face_detected_again(astronaut):
    tracker = FaceTracker(threads=2, mask=False)
    first = tracker(astronaut)
    second = tracker(astronaut)
    assert second.face.tracked and not first.face.tracked and second.mask is None
    assert np.abs(second.face.landmarks[:, :2] - first.face.landmarks[:, :2]).mean() < 2.0
    assert tracker(np.zeros_like(astronaut)).face is None
    assert not tracker(astronaut).face.tracked


def test_a_frame_of_another_shape_is_named(tracker):
    with pytest.raises(InputError, match="frame.*expected an \\(H, W, 3\\) RGB image"):
        tracker(np.zeros((8, 8)))


def test_ibug68_takes_68_distinct_mesh_points(found):
    assert len(IBUG68_FROM_MESH) == 68 == len(set(IBUG68_FROM_MESH)) and max(IBUG68_FROM_MESH) < 468
    points = ibug68(found.face.landmarks)
    assert points.shape == (68, 2)
    assert np.all(np.abs(points[[36, 45]] - EYE_CENTRES).max(1) < 15)  # the outer eye corners near the eyes


def test_the_mapping_follows_the_procedural_heads_own_ibug_points(tracker, procedural_head):
    """One frontal render of the head the mapping was derived on: the mapped points lie near the head's
    own iBUG points (scripts/derive_ibug68_mapping.py derives it again from 90 views)."""
    from mogaface.core.data.head_preview import view_camera
    from mogaface.core.data.mesh_render import render_mesh
    from mogaface.core.flame.landmarks import procedural_embedding

    vertices, faces = procedural_head["v_template"], procedural_head["f"]
    camera = view_camera(vertices, 0.0, 0.0, 256)
    rgb, _ = render_mesh(vertices, faces, procedural_head["vt"], procedural_head["ft"],
                         procedural_head["texture"].astype(np.float32) / 255.0, camera, background=(0.5, 0.5, 0.5),
                         supersample=2)
    embedding = procedural_embedding()
    truth, _ = camera.project(embedding.positions(vertices, faces)[np.argsort(embedding.ibug)])
    mesh = tracker((rgb * 255 + 0.5).astype(np.uint8)).face.landmarks
    found = derive([(truth, mesh)])
    eye_distance = np.linalg.norm(truth[36] - truth[45])
    error = np.linalg.norm(ibug68(mesh) - truth, axis=1) / eye_distance
    assert error[17:].mean() < 0.06 and error.max() < 0.15
    assert found["error"].mean() <= error.mean() + 1e-9  # this view's own assignment fits it at least as well


def test_the_overlay_draws_on_the_frame(found, astronaut):
    image = draw_overlay(astronaut, found)
    assert image.shape == astronaut.shape and image.dtype == np.uint8
    assert np.any(np.all(image == (80, 230, 80), axis=-1))  # mesh points
    zoomed = draw_overlay(astronaut, found, crop=(150, 50, 300, 200), zoom=2)
    assert zoomed.shape == (300, 300, 3)


# -- the model files ------------------------------------------------------------------------------

@pytest.fixture
def model_copy(tmp_path, monkeypatch):
    folder = tmp_path / "face"
    folder.mkdir()
    for path in models.find_all().values():
        shutil.copy(path, folder / path.name)
    monkeypatch.setenv(models.ENV_VAR, str(folder))
    return folder


def test_a_truncated_model_is_refused_by_name(model_copy):
    path = model_copy / models.MODELS["landmarks"].name
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(InputError, match="face_landmark.tflite: sha256 .* is not the pinned .*landmarks model"):
        FaceTracker()


def test_a_model_of_another_hash_or_missing_is_refused_by_name(model_copy):
    iris = model_copy / models.MODELS["iris"].name
    shutil.copy(model_copy / models.MODELS["detector"].name, iris)
    with pytest.raises(InputError, match="iris_landmark.tflite: sha256 .* is not the pinned"):
        models.find("iris")
    iris.unlink()
    with pytest.raises(InputError, match=f"iris_landmark.tflite: face model not found \\(named by {models.ENV_VAR}\\)"):
        models.find_all()


def test_install_takes_the_four_pinned_files_from_the_wheel(tmp_path):
    import zipfile

    wheel = tmp_path / models.WHEEL_NAME
    with zipfile.ZipFile(wheel, "w") as archive:
        for role, path in models.find_all().items():
            archive.writestr(models.MODELS[role].member, path.read_bytes() if role != "iris" else b"not a model")
    with pytest.raises(InputError, match="iris_landmark.tflite.*sha256 .* is not the pinned"):
        models.install_from_wheel(wheel, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written before every file is checked
    with zipfile.ZipFile(wheel, "w") as archive:
        for role, path in models.find_all().items():
            archive.writestr(models.MODELS[role].member, path.read_bytes())
    installed = models.install_from_wheel(wheel, tmp_path / "out")
    assert sorted(p.name for p in installed) == sorted(pinned.name for pinned in models.MODELS.values())
    assert models.main(["check", "--dest", str(tmp_path / "out")]) == 0
