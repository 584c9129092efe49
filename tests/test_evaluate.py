"""Evaluation protocols: which frames each scores, where parameters come from, honest scoring."""

import json

import numpy as np
import pytest
from test_evaluate_fixtures import (  # noqa: F401 (fixtures)
    EXPR_NUDGE,
    capture_fixture,
    driver_capture,
    fake_run,
    render_np,
    run_fixture,
    tiny_capture,
)

from mogaface.core.cli import main
from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.evaluate.evaluation import evaluate_run
from mogaface.core.evaluate.protocols import (
    DrivenParams,
    TrackedParams,
    protocol_frames,
    render_frame,
    run_protocol,
    views_at,
)
from mogaface.core.metrics import images as metrics
from mogaface.core.run.folder import RunFolder


def test_protocol_frames(capture):
    train_timesteps = {f.timestep_index for f in capture.frames("train")}
    novel = protocol_frames(capture, "novel_view")
    assert {f.camera_id for f in novel} == {"cam01"}  # the held-out camera
    assert {f.timestep_index for f in novel} == train_timesteps
    reenact = protocol_frames(capture, "self_reenactment")
    assert {f.sequence for f in reenact} == {"FREE"}
    assert {f.camera_id for f in reenact} == set(capture.cameras)
    assert not {f.timestep_index for f in reenact} & train_timesteps
    thinned = protocol_frames(capture, "novel_view", max_frames=3)
    assert len(thinned) == 3 and thinned[0] == novel[0] and thinned[-1] == novel[-1]
    with pytest.raises(InputError, match="unknown protocol"):
        protocol_frames(capture, "cross")


def test_tracked_params_run_first_then_capture_with_run_identity(capture, run):
    source = TrackedParams(capture, run)
    trained = source.params_for(0)
    np.testing.assert_allclose(trained["expr"][0], capture.flame_params(0)["expr"][0] + EXPR_NUDGE, rtol=1e-6)
    unseen = source.params_for(13)
    assert 13 not in run.trained_timesteps
    np.testing.assert_array_equal(unseen["expr"], capture.flame_params(13)["expr"])
    np.testing.assert_allclose(unseen["shape"], capture.flame_params(13)["shape"] + 0.1, rtol=1e-6)


def test_the_scored_view_is_never_a_source_input(capture, run, tmp_path):
    """Every parameter request names the scored camera as excluded (the hook image-assisted
    inference must honour), and an image-assisted source sees only the other views."""
    calls = []

    class Spy(TrackedParams):
        description = "spy"

        def params_for(self, frame, exclude_view=None):
            calls.append((frame, exclude_view, [v.camera_id for v in views_at(capture, frame.timestep_index, exclude_view)]))
            return super().params_for(frame, exclude_view)

    frames = protocol_frames(capture, "self_reenactment", max_frames=2)
    items = list(run_protocol(run.load_avatar(), capture, Spy(capture, run), frames, run.background))
    assert [i.frame for i in items] == frames
    assert [c[0] for c in calls] == frames
    for frame, excluded, seen in calls:
        assert excluded == frame.camera_id
        assert frame.camera_id not in seen and len(seen) == len(capture.cameras) - 1
    calls.clear()
    result = evaluate_run(run.root, ["novel_view"], 1, lpips=False, out_dir=tmp_path, source=Spy(capture, run))
    assert result["inference"] == "spy" and "spy" in (tmp_path / "metrics.md").read_text()
    assert [(c[0].camera_id, c[1]) for c in calls] == [("cam01", "cam01")]


def test_driven_params_keep_identity_take_motion(capture, run, tmp_path_factory):
    driver = Capture.open(driver_capture(tmp_path_factory))
    identity = run.identity_params()
    params = DrivenParams(identity, driver).params_for(5)
    np.testing.assert_array_equal(params["shape"], identity["shape"])
    for key in ("expr", "jaw_pose", "eyes_pose", "neck_pose", "rotation", "translation"):
        np.testing.assert_array_equal(params[key], driver.flame_params(5)[key])
    assert not np.allclose(params["shape"], driver.flame_params(5)["shape"])
    n = len(params["expr"])
    longer = DrivenParams(identity, driver, n_expr=n + 3).params_for(5)["expr"]
    np.testing.assert_array_equal(longer, np.concatenate([params["expr"], np.zeros(3, np.float32)]))
    np.testing.assert_array_equal(DrivenParams(identity, driver, n_expr=n - 2).params_for(5)["expr"], params["expr"][:-2])


def test_evaluate_run_scores_full_images(capture, run, tmp_path):
    result = evaluate_run(run.root, max_frames=2, out_dir=tmp_path, comparisons=1)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert set(on_disk["protocols"]) == {"novel_view", "self_reenactment"}
    novel = result["protocols"]["novel_view"]
    assert novel["frames"] == 2 and set(novel["per_camera"]) == {"cam01"}
    assert len(on_disk["protocols"]["novel_view"]["per_frame"]) == 2
    assert 0 < novel["lpips"] < 1 and -1 < novel["ssim"] < 1 and 5 < novel["psnr"] < 60
    # The mean is the mean of per-frame scores of the full image against the stored frame.
    frames = protocol_frames(capture, "novel_view", max_frames=2)
    source = TrackedParams(capture, run)
    avatar = run.load_avatar()
    scores = []
    for frame in frames:
        prediction, _ = render_frame(avatar, source.params_for(frame, frame.camera_id), capture.camera(frame), run.background)
        scores.append(metrics.psnr(prediction, capture.load_image(frame)[0]))
    assert novel["psnr"] == pytest.approx(np.mean(scores), rel=1e-6)
    table = (tmp_path / "metrics.md").read_text()
    assert "| novel view | 2 |" in table and "| self reenactment | 2 |" in table
    comparisons = sorted((tmp_path / "eval").glob("*.png"))
    assert len(comparisons) == 2
    from mogaface.core.io.image import read_image

    assert read_image(comparisons[0]).shape == (48, 3 * 48, 3)


def test_eval_cli_with_driver(run, tmp_path, tmp_path_factory, capsys):
    driver = driver_capture(tmp_path_factory)
    code = main(["eval", str(run.root), "--protocols", "novel_view", "--max-frames", "2", "--no-lpips",
                 "--driver", str(driver), "--driver-cameras", "cam00,cam02", "--out", str(tmp_path), "--quiet"])
    assert code == 0
    result = json.loads((tmp_path / "metrics.json").read_text())
    assert list(result["protocols"]) == ["novel_view"] and "lpips" not in result["protocols"]["novel_view"]
    cross = result["cross_identity"]
    assert cross["frames"] == 2 * 2 and "psnr" not in cross  # 2 driver timesteps x 2 cameras, no metrics
    strip = tmp_path / "eval" / "cross_identity" / "strip.png"
    from mogaface.core.io.image import read_image

    assert read_image(strip).shape == (2 * 48, 2 * 48, 3)
    last = Capture.open(driver).timesteps[-1]  # 17: the driver's last timestep (its validation sequence's)
    assert sorted(p.name for p in strip.parent.glob("0*.png")) == ["00000_cam00.png", "00000_cam02.png",
                                                                   f"{last:05d}_cam00.png", f"{last:05d}_cam02.png"]
    assert "novel view" in capsys.readouterr().out
    # What was written is subject A posed by B's motion, as the avatar renders it.
    avatar, own_capture = run.load_avatar(), Capture.open(run.capture_root)
    camera = own_capture.cameras["cam02"]
    driven, _ = render_np(avatar, DrivenParams(run.identity_params(), Capture.open(driver)).params_for(last), camera)
    written = read_image(strip.parent / f"{last:05d}_cam02.png")
    np.testing.assert_allclose(written, np.clip(driven, 0, 1), atol=1 / 255 + 1e-6)
    own, _ = render_np(avatar, TrackedParams(own_capture, run).params_for(last), camera)
    assert np.abs(np.clip(own, 0, 1) - written).max() > 0.05  # not A's own performance


def test_eval_cli_reports_a_missing_run(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "nowhere")]) == 2
    assert "not a run folder" in capsys.readouterr().err


def test_target_is_composited_only_off_the_recorded_background(capture):
    from mogaface.core.evaluate.protocols import target_image

    frame = capture.frames("val")[0]
    rgb, mask = capture.load_image(frame)
    assert 0 < mask.mean() < 1
    np.testing.assert_array_equal(target_image(capture, frame, (1, 1, 1), (1.0, 1.0, 1.0)), rgb)
    black = target_image(capture, frame, (0, 0, 0), (1.0, 1.0, 1.0))
    np.testing.assert_allclose(black, rgb * mask[..., None], atol=1e-6)
    assert black[mask == 0].max() == 0


def test_run_folder_reads_background_identity_and_relative_capture(run, tmp_path):
    import shutil

    assert run.trained_timesteps == list(range(12)) and run.background == (1.0, 1.0, 1.0)
    identity = run.identity_params()  # the capture writes a zero static_offset, as GaussianAvatars needs
    assert set(identity) == {"shape", "static_offset"} and not identity["static_offset"].any()
    moved = tmp_path / "run"
    shutil.copytree(run.root, moved)
    shutil.copytree(run.capture_root, tmp_path / "cap", ignore=shutil.ignore_patterns("images", "fg_masks"))
    (moved / "run.json").write_text(json.dumps({"capture": "../cap", "background": [0, 0.5, 1]}))
    other = RunFolder(moved)
    assert other.capture_root.resolve() == (tmp_path / "cap").resolve() and other.background == (0, 0.5, 1)
    (moved / "run.json").write_text(json.dumps({"capture": "../cap", "background": [2, 0, 0]}))
    with pytest.raises(InputError, match="background"):
        RunFolder(moved)


def test_lpips_on_images_too_small_for_it_names_the_capture(capture):
    """Captures may hold images from 11 px a side (the SSIM window); LPIPS needs 32."""
    import types

    from mogaface.core.evaluate.protocols import check_lpips_size

    small = types.SimpleNamespace(root=capture.root, cameras={
        **capture.cameras, "cam09": types.SimpleNamespace(width=24, height=20)})
    with pytest.raises(InputError, match=r"field 'images'.*at least 32 x 32 pixels.*24 x 20.*--no-lpips") as error:
        check_lpips_size(small)
    assert str(capture.root) in str(error.value)
    check_lpips_size(capture)  # 48 px: scored with LPIPS


def test_a_strip_of_cameras_of_several_sizes_pads_them():
    """A tracked folder of photos has a camera per photo, each its own size: the strip pads."""
    from mogaface.core.evaluate.report import strip_image

    small, large = np.ones((4, 3, 3)), np.full((6, 5, 3), 0.5)
    strip = strip_image([[small, large], [large, small]])
    assert strip.shape == (12, 10, 3)
    assert (strip[:4, :3] == 1).all() and (strip[4:6, :3] == 0).all() and (strip[:6, 5:10] == 0.5).all()
