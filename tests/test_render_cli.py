"""The render command: timestep lists, PNG on the training background, RGBA EXR with alpha."""

import numpy as np
import pytest
from test_evaluate_fixtures import fake_run, render_np, tiny_capture

from mogaface.core.cli import main
from mogaface.core.cli.render import parse_timesteps
from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.evaluate.protocols import TrackedParams
from mogaface.core.io.image import linear_to_srgb, read_image
from mogaface.core.run.folder import RunFolder, load_flame_file


def test_parse_timesteps():
    assert parse_timesteps("0,5,10-12") == [0, 5, 10, 11, 12]
    assert parse_timesteps(" 3 , 1-2,3") == [3, 1, 2]
    for bad in ("", "a", "5-3", "-1", "1,,2", "1-"):
        with pytest.raises(InputError, match="--timesteps"):
            parse_timesteps(bad)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    run = RunFolder(fake_run(tmp_path_factory))
    capture = Capture.open(tiny_capture(tmp_path_factory))
    return run, capture, run.load_avatar()


def test_render_png_and_exr(setup, tmp_path, capsys):
    run, capture, avatar = setup
    assert main(["render", str(run.root), "--timesteps", "0,13", "--camera", "cam02", "--out", str(tmp_path), "--exr"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["00000_cam02.exr", "00000_cam02.png", "00013_cam02.exr", "00013_cam02.png"]
    source = TrackedParams(capture, run)
    for t in (0, 13):
        expected, alpha = render_np(avatar, source.params_for(t), capture.cameras["cam02"])
        png = read_image(tmp_path / f"{t:05d}_cam02.png")
        np.testing.assert_allclose(png, np.clip(expected, 0, 1), atol=1 / 255 + 1e-6)
        exr = read_image(tmp_path / f"{t:05d}_cam02.exr")
        assert exr.shape == (48, 48, 4)
        np.testing.assert_allclose(exr[..., 3], alpha, atol=1e-6)
        assert 0 < alpha.mean() < 1  # both covered and empty pixels
        # Un-premultiplied, back to sRGB and over white, the EXR is the PNG's image.
        a = exr[..., 3:]
        straight = linear_to_srgb(np.where(a > 1e-6, exr[..., :3] / np.maximum(a, 1e-6), 0))
        np.testing.assert_allclose(straight * a + (1 - a), np.clip(expected, 0, 1), atol=2e-3)
    assert "00013_cam02.exr" in capsys.readouterr().out


def test_render_defaults_and_params_dir(setup, tmp_path):
    run, capture, avatar = setup
    assert main(["render", str(run.root), "--timesteps", "2", "--params", str(capture.root / "flame_param_gt")]) == 0
    out = run.root / "renders" / "00002_cam01.png"  # default folder and the held-out camera
    truth_params = load_flame_file(capture.root / "flame_param_gt" / "00002.npz")
    expected, _ = render_np(avatar, truth_params, capture.cameras["cam01"])
    tracked, _ = render_np(avatar, TrackedParams(capture, run).params_for(2), capture.cameras["cam01"])
    assert np.abs(expected - tracked).max() > 0.05  # the parameter folder matters
    np.testing.assert_allclose(read_image(out), np.clip(expected, 0, 1), atol=1 / 255 + 1e-6)


def test_render_errors(setup, tmp_path, capsys):
    run, _, _ = setup
    assert main(["render", str(run.root), "--timesteps", "0", "--camera", "cam99", "--out", str(tmp_path)]) == 2
    assert "cam99" in capsys.readouterr().err
    assert main(["render", str(run.root), "--timesteps", "0", "--params", str(tmp_path), "--out", str(tmp_path)]) == 2
    assert "00000.npz" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.png"))
