"""Synthetic captures rendered by Cycles (``make-capture --renderer cycles``): a tiny capture made end
to end by the child process, resuming by image, and the Blender-free parts (materials, wrinkle
maps and their drivers, hair strands bound to triangles, cameras that disagree in colour)."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from mogaface.core.data import cycles_job
from mogaface.core.data.camera_colour import CameraColour, composite, draw_camera_colours, foreground
from mogaface.core.data.capture_settings import CaptureSettings
from mogaface.core.data.cycles_hair import grow_strands
from mogaface.core.data.cycles_skin import EYE, MOUTH, SKIN, WRINKLES, WrinkleDriver, face_materials, surface_maps
from mogaface.core.errors import InputError
from mogaface.core.flame.expression_roles import LEFT_EYE, RIGHT_EYE, mouth_components
from mogaface.core.flame.landmarks import model_landmarks
from mogaface.core.flame.model import FlameModel

TINY = CaptureSettings(subject=1, views=2, timesteps=16, size=32, renderer="cycles", samples=2, camera_colour=1.0)


@pytest.fixture(scope="module")
def head(procedural_head_pkl):
    model = FlameModel.load(procedural_head_pkl)
    with torch.no_grad():
        rest = model()[0].double().numpy()
    return model, rest


@pytest.fixture(scope="module")
def maps(head):
    model, rest = head
    marks = model_landmarks(model.arrays.faces).positions(rest, model.arrays.faces)
    return surface_maps(model.arrays, rest, marks, 256)


@pytest.fixture(scope="module")
def cycles_capture(tmp_path_factory):
    from mogaface.core.data.generator import make_capture

    return make_capture(tmp_path_factory.mktemp("cycles") / "cap", TINY, progress=False, threads=2)


def test_a_cycles_capture_passes_the_full_check_and_keeps_its_answers_aside(cycles_capture):
    from mogaface.core.data.validate import validate_capture

    summary = validate_capture(cycles_capture, full=True)
    assert summary.views == 2 and not (cycles_capture / cycles_job.JOB_DIR).exists()
    info = json.loads((cycles_capture / "capture_info.json").read_text())
    assert info["settings"]["renderer"] == "cycles" and info["ground_truth"]["camera_colour"] == "camera_colour_gt.json"
    truth = json.loads((cycles_capture / "camera_colour_gt.json").read_text())
    assert len({round(c["exposure"], 6) for c in truth.values()}) == 2  # the cameras disagree
    for split in ("train", "val", "test"):
        assert "colour" not in (cycles_capture / f"transforms_{split}.json").read_text()


def test_cycles_images_show_the_head_over_the_background(cycles_capture):
    from mogaface.core.data.capture import Capture

    capture = Capture.open(cycles_capture)
    frame = capture.frames("train")[0]
    rgb, mask = capture.load_image(frame)
    assert 0.1 < mask.mean() < 0.9
    assert np.allclose(rgb[mask < 1e-3], 1.0, atol=1e-2)  # the background stays the trainers' white
    assert rgb[mask > 0.99].mean() < 0.9  # the head is shaded, not blown out


def test_the_renderer_resumes_shares_between_machines_and_starts_over_for_other_settings(tmp_path, head):
    model, rest = head
    from mogaface.core.data.generator import camera_dome, moments
    from mogaface.core.data.sequences import make_sequences

    cameras, _ = camera_dome(2, 32, rest, np.random.default_rng(0))
    sequences = make_sequences(16, model.n_shape, model.n_expr, mouth_components(model.arrays), seed=0)
    first_two = [m for m in moments(sequences, [0.0, 0.0]) if m[0] < 2]
    root = tmp_path / cycles_job.JOB_DIR
    settings = dataclasses.replace(TINY, samples=1)
    frames = cycles_job.write_job(root, model, cameras, first_two, [0.0, 0.0], settings)
    assert cycles_job.run_child(root, 2, progress=False, part=(2, 2)) == 2  # one machine's share
    assert sorted(p.name for p in (root / "renders").glob("*.exr")) == ["00001_00.exr", "00001_01.exr"]
    assert cycles_job.run_child(root, 2, progress=False) == 2  # the rest: what is missing
    (root / "renders" / frames[2]["image"]).unlink()
    assert cycles_job.run_child(root, 2, progress=False) == 1  # only the missing image
    linear, alpha = cycles_job.CyclesImages(root).image(0, 1)
    assert linear.shape == (32, 32, 3) and alpha.max() > 0.9 and np.isfinite(linear).all()
    cycles_job.write_job(root, model, cameras, first_two, [0.0, 0.0], dataclasses.replace(settings, samples=2))
    assert not (root / "renders").exists()  # renders of other settings are never reused


def test_a_share_is_every_nth_moment_and_a_bad_one_is_refused():
    frames = [{"moment": m, "camera": c} for m in ("a", "b", "c") for c in (0, 1)]
    assert cycles_job.in_part(frames, (2, 2)) == [False, False, True, True, False, False]
    assert cycles_job.parse_part("3/3") == (3, 3)
    for bad in ("0/2", "3/2", "1", "a/b"):
        with pytest.raises(InputError, match="render part"):
            cycles_job.parse_part(bad)


def test_without_bpy_the_cycles_renderer_is_refused_naming_the_module(monkeypatch):
    monkeypatch.setattr(cycles_job.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(InputError, match="bpy"):
        cycles_job.check_bpy()


def test_materials_follow_the_eye_joints_and_the_mouth(head):
    model, _ = head
    arrays = model.arrays
    material = face_materials(arrays)
    eyeball = arrays.weights[:, LEFT_EYE] + arrays.weights[:, RIGHT_EYE] > 0.5
    assert np.array_equal(material == EYE, eyeball[arrays.faces].all(1))
    assert (material == MOUTH).sum() > 100 and (material == SKIN).mean() > 0.7


def test_wrinkle_maps_lie_on_the_skin_where_the_face_folds(head, maps):
    model, rest = head
    marks = model_landmarks(model.arrays.faces).positions(rest, model.arrays.faces)
    face, bary = maps["texel_face"], maps["texel_bary"]
    covered = face >= 0
    where = np.zeros(face.shape + (3,))
    where[covered] = np.einsum("nk,nkc->nc", bary[covered], rest[model.arrays.faces[face[covered]]])
    forehead = maps["wrinkles"][..., WRINKLES.index("forehead")] > 0.5
    assert forehead.sum() > 50 and (where[forehead][:, 1] > marks[17:27, 1].min()).all()
    assert maps["wrinkles"][~covered].max() == 0.0
    assert 0.2 <= maps["roughness"][covered].min() and maps["roughness"][covered].max() <= 0.8


def test_a_sided_smile_folds_its_own_side_only(head):
    model, rest = head
    driver = WrinkleDriver(model.arrays, rest)
    names = model.expression_names
    smile = np.zeros(model.n_expr)
    smile[names.index("smile_left")] = 2.0
    weights = driver.weights(smile)[:, WRINKLES.index("crows_feet")]
    side = np.sign(rest[:, 0])
    assert weights[side > 0].mean() != pytest.approx(weights[side < 0].mean(), abs=0.5)
    assert driver.weights(np.zeros(model.n_expr)).max() == 0.0
    anonymous = dataclasses.replace(model.arrays, expression_names=[f"expr{i:03d}" for i in range(model.n_expr)])
    assert WrinkleDriver(anonymous, rest).weights(smile).max() == 0.0  # no names: no wrinkles


def test_strands_turn_and_move_with_the_skin(head, maps):
    model, rest = head
    arrays = model.arrays
    marks = model_landmarks(arrays.faces).positions(rest, arrays.faces)
    strands = grow_strands(arrays, rest, maps["texel_face"], maps["texel_bary"], marks,
                           face_materials(arrays) == SKIN, np.random.default_rng(0), scalp=300, brow=40, lash=10)
    assert set(np.unique(strands.kind)) == {0, 1, 2}
    angle = 0.4
    turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    shift = np.array([0.01, -0.02, 0.03])
    moved = strands.positions(rest @ turn.T + shift, arrays.faces)
    assert np.allclose(moved, strands.positions(rest, arrays.faces) @ turn.T + shift, atol=1e-9)
    roots = np.einsum("sk,skc->sc", strands.bary, rest[arrays.faces[strands.face]])
    assert np.allclose(strands.positions(rest, arrays.faces)[:, 0], roots, atol=1e-9)


def test_camera_colour_changes_the_foreground_only_and_undoes_exactly():
    rng = np.random.default_rng(3)
    alpha = np.clip(rng.uniform(-0.5, 1.5, (8, 10)), 0, 1).astype(np.float32)
    linear = rng.uniform(0.05, 0.8, (8, 10, 3)).astype(np.float32)
    background = (1.0, 1.0, 1.0)
    rgb = composite(linear, alpha, background)
    assert np.allclose(foreground(rgb, alpha, background)[alpha > 0.05], linear[alpha > 0.05], atol=2e-3)
    colour = CameraColour(exposure=0.5, gains=(1.1, 1.0, 0.9), vignette=0.0)
    seen = colour.seen(linear)
    assert np.allclose(seen / linear, np.float32(2 ** 0.5) * np.array([1.1, 1.0, 0.9], np.float32), rtol=1e-5)
    assert np.array_equal(composite(seen, alpha, background)[alpha == 0], rgb[alpha == 0])
    corner, centre = CameraColour(vignette=0.3).factor(9, 9)[[0, 4], [0, 4], 0]
    assert corner < centre == pytest.approx(1.0, abs=0.01)
    assert draw_camera_colours(3, 0.0, rng) == [CameraColour()] * 3
