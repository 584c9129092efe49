"""Cameras that disagree in colour: the affine map of a render's foreground, the colours training
learns per camera (identity at the start, their mean held at the identity, saved and resumed), the
run's loader and the protocols that apply them, and the held-out camera's colour fitted on half
its frames and scored on the other half."""

import json
import shutil

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import fake_run, render_np, tiny_capture, watch_target_images

from mogaface.core.avatar.camera_colour import matrix_and_offset, read_camera_colours, recolour
from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.evaluate.camera_alignment import fit_colour, split_frames
from mogaface.core.evaluate.protocols import TrackedParams, protocol_frames, run_protocol
from mogaface.core.io.image import write_png
from mogaface.core.run.folder import RunFolder
from mogaface.core.run.names import COLOURS_FILE
from mogaface.core.train import config as C
from mogaface.core.train.camera_colour import CameraColours
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint
from mogaface.core.train.trainer import Trainer

# Two training cameras that see the head in other colours: red and blue gains apart, a little green.
TRUE_CHANGES = {"cam00": np.diag([-0.2, 0.05, 0.2]) @ np.eye(3, 4), "cam02": np.diag([0.2, -0.05, -0.2]) @ np.eye(3, 4)}


def composite(generator, size=(5, 7)):
    """Random straight colours, coverage (some pixels empty, some full) and a background."""
    colours = torch.rand(*size, 3, generator=generator, dtype=torch.float64)
    alpha = torch.rand(*size, generator=generator, dtype=torch.float64)
    alpha[0, 0], alpha[0, 1] = 0.0, 1.0
    background = torch.rand(3, generator=generator, dtype=torch.float64)
    return colours, alpha, background


def test_the_map_recolours_the_foreground_only_and_is_exact_at_the_identity():
    generator = torch.Generator().manual_seed(0)
    colours, alpha, background = composite(generator)
    rgb = alpha[..., None] * colours + (1 - alpha[..., None]) * background
    change = 0.2 * torch.randn(3, 4, generator=generator, dtype=torch.float64)
    matrix, offset = (torch.from_numpy(v) for v in matrix_and_offset(change.numpy()))
    # Independently: each straight colour mapped, then composited over the untouched background.
    expected = alpha[..., None] * (colours @ matrix.T + offset) + (1 - alpha[..., None]) * background
    assert torch.allclose(recolour(rgb, alpha, background, change), expected, atol=1e-12)
    assert torch.equal(recolour(rgb, alpha, background, change)[0, 0], rgb[0, 0])  # nothing covers it: background
    white = torch.ones(4, 4, 3)
    assert torch.equal(recolour(white, torch.zeros(4, 4), (1.0, 1.0, 1.0), change.float()), white)
    rgb32, alpha32 = rgb.float(), alpha.float()
    assert torch.equal(recolour(rgb32, alpha32, background.float(), torch.zeros(3, 4)), rgb32)  # bit for bit


def test_gradients_of_the_map_and_of_the_learned_colours():
    generator = torch.Generator().manual_seed(1)
    colours, alpha, background = composite(generator, (3, 4))
    rgb = (alpha[..., None] * colours + (1 - alpha[..., None]) * background).requires_grad_()
    alpha = alpha.clone().requires_grad_()
    change = (0.2 * torch.randn(3, 4, generator=generator, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda r, a, c: recolour(r, a, background, c), (rgb, alpha, change))

    # The module's gradient of a loss against its parameter, against the closed form
    # dL/d[M − I | b] = Σ_pixels g ⊗ [F, α] (F = rgb − (1 − α)·bg) and the penalty's 2·change.
    colours_module = CameraColours(["cam00", "cam02"])
    with torch.no_grad():
        colours_module.change[0].copy_(change.detach().float())
    weights = torch.randn(3, 4, 3, generator=generator).float()
    out = colours_module.apply("cam00", rgb.detach().float(), alpha.detach().float(), background.float())
    ((out * weights).sum() + colours_module.penalty("cam00")).backward()
    a = alpha.detach().float()[..., None]
    foreground = rgb.detach().float() - (1 - a) * background.float()
    inputs = torch.cat([foreground, a], -1).reshape(-1, 4)
    closed_form = weights.reshape(-1, 3).T @ inputs + 2 * change.detach().float()
    assert torch.allclose(colours_module.change[0].grad, closed_form, atol=1e-5)
    assert colours_module.change[1].grad is None  # a camera the step did not render: Adam leaves it
    assert torch.equal(colours_module.apply("cam01", out, a[..., 0], background), out)  # no map: as it is


def test_the_gauge_the_state_and_the_file(tmp_path):
    colours = CameraColours(["cam02", "cam00", "cam03"])
    assert colours.ids == ["cam00", "cam02", "cam03"]
    assert all(torch.equal(v, torch.zeros(3, 4)) for v in colours.values().values())  # the identity at the start
    generator = torch.Generator().manual_seed(2)
    values = {cid: 0.1 * torch.randn(3, 4, generator=generator) for cid in colours.ids}
    colours.start_from(values)
    colours.fix_gauge()
    learned = colours.values()
    assert torch.allclose(torch.stack(list(learned.values())).mean(0), torch.zeros(3, 4), atol=1e-7)
    assert torch.allclose(learned["cam00"] - learned["cam02"], values["cam00"] - values["cam02"], atol=1e-6)

    again = CameraColours(["cam00", "cam02", "cam03"])
    again.load(colours.state())
    assert all(torch.equal(again.values()[c], learned[c]) for c in learned)
    with pytest.raises(InputError, match="other cameras"):
        CameraColours(["cam00"]).load(colours.state())

    colours.write(tmp_path / COLOURS_FILE)
    read = read_camera_colours(tmp_path / COLOURS_FILE)
    assert set(read) == set(learned)
    assert all(np.allclose(read[c], learned[c].numpy(), atol=1e-7) for c in learned)
    entry = json.loads((tmp_path / COLOURS_FILE).read_text())["cam00"]
    assert np.allclose(entry["matrix"], np.eye(3) + learned["cam00"][:, :3].numpy(), atol=1e-7)
    (tmp_path / "bad.json").write_text(json.dumps({"cam07": {"matrix": [[1, 0, 0], [0, 1, 0]], "offset": [0, 0, 0]}}))
    with pytest.raises(InputError, match="cam07"):
        read_camera_colours(tmp_path / "bad.json")


def _config(steps, colour, **cameras):
    return C.resolve(overrides={
        "train": {"steps": steps, "threads": 1, "log_every": 1, "checkpoint_every": 4},
        "densify": {"start": 2, "stop": 10, "interval": 3, "grad_threshold": 1e-6, "opacity_reset_interval": 0,
                    "sh_degree_interval": 4, "max_gaussians": 20000, "percent_dense": 0.005},
        "eval": {"at_end": False, "lpips": False},
        "cameras": {"colour": colour, "colour_begin": 0.0, **cameras},
    })


def test_colours_that_cannot_move_change_nothing(tmp_path_factory, tmp_path):
    """A run whose colours cannot move (rate 0, no penalty) is bit for bit the run without them: the
    identity map, its penalty and its gauge change nothing (and a run without them writes none)."""
    capture = tiny_capture(tmp_path_factory)
    Trainer(capture, tmp_path / "off", _config(8, False)).run()
    Trainer(capture, tmp_path / "still", _config(8, True, colour_lr=0.0, colour_weight=0.0)).run()
    off, still = (load_checkpoint(latest_checkpoint(tmp_path / name / "checkpoints")) for name in ("off", "still"))
    assert "colours" not in off and not (tmp_path / "off" / COLOURS_FILE).exists()
    for name, value in off["avatar"]["gaussians"].items():
        assert torch.equal(value, still["avatar"]["gaussians"][name]), name
    assert not still["colours"]["change"].any()
    with pytest.raises(InputError, match="no camera colours"):
        Trainer(capture, tmp_path / "off", _config(12, True), resume=True)


def test_the_colours_reach_the_checkpoint_and_the_run_folder_and_resume_exactly(tmp_path_factory, tmp_path):
    capture = tiny_capture(tmp_path_factory)
    config = _config(8, True, colour_lr=0.02, colour_weight=0.01)
    Trainer(capture, tmp_path / "straight", config).run()
    assert Trainer(capture, tmp_path / "split", config).run(until=4)["step"] == 4
    Trainer(capture, tmp_path / "split", resume=True).run()
    straight, split = (read_camera_colours(tmp_path / name / COLOURS_FILE) for name in ("straight", "split"))
    assert set(straight) == {"cam00", "cam02"} and np.abs(straight["cam00"]).max() > 1e-3  # they moved
    assert np.allclose(straight["cam00"], -straight["cam02"], atol=1e-6)  # two cameras, mean at the identity
    assert all(np.array_equal(straight[c], split[c]) for c in straight)

    # A run (a camera round) whose cameras start from a file starts from the colours beside it.
    from mogaface.core.data.camera_file import write_cameras

    cameras = Capture.open(capture)
    beside = tmp_path / "round1"
    beside.mkdir()
    write_cameras(beside / "cameras_refined.json", {f.camera_id: cameras.camera(f) for f in cameras.frames("train")})
    shutil.copyfile(tmp_path / "straight" / COLOURS_FILE, beside / COLOURS_FILE)
    started = Trainer(capture, tmp_path / "round2", _config(8, True, refine=True, start=str(beside / "cameras_refined.json")))
    assert all(np.allclose(started.camera_colours.values()[c].numpy(), straight[c], atol=1e-6) for c in straight)


@pytest.fixture(scope="module")
def recoloured(tmp_path_factory):
    """The tiny capture with its two training cameras' images seen through :data:`TRUE_CHANGES`."""
    root = tmp_path_factory.mktemp("recoloured") / "capture"
    shutil.copytree(tiny_capture(tmp_path_factory), root)
    capture = Capture.open(root)
    for frame in capture.frames("train"):
        rgb, alpha = (torch.from_numpy(np.array(x, np.float32)) for x in capture.load_image(frame))
        write_png(root / frame.file_path, recolour(rgb, alpha, (1.0, 1.0, 1.0), TRUE_CHANGES[frame.camera_id]).clamp(0, 1).numpy())
    return root


def test_training_learns_how_the_cameras_disagree(recoloured, tmp_path):
    """Without view-dependent colour (SH degree 0) an avatar cannot show one surface in two colours;
    with the cameras' colours it can: its training views fit better, and the map between the two
    cameras' colours learned is the true one, on the avatar's own colours. (Changes this large, in
    this few steps, want a weaker penalty than the default's.)"""
    def train(colour):
        config = C.resolve(overrides={
            "train": {"steps": 200, "threads": 1, "log_every": 50, "checkpoint_every": 0},
            "densify": {"start": 1000, "stop": 2000, "opacity_reset_interval": 0, "max_sh_degree": 0},
            "lr": {"color": 0.01}, "eval": {"at_end": False, "lpips": False},
            "cameras": {"colour": colour, "colour_lr": 0.005, "colour_begin": 0.3, "colour_weight": 0.01}})
        trainer = Trainer(recoloured, tmp_path / str(colour), config)
        trainer.run()
        with torch.no_grad():
            l1 = np.mean([float(trainer.views.render(f, trainer.step, torch.Generator()).losses["l1"])
                          for f in trainer.data.frames])
        return trainer, l1

    plain, plain_l1 = train(False)
    learned, learned_l1 = train(True)
    assert learned_l1 < 0.98 * plain_l1, (learned_l1, plain_l1)
    frame = learned.data.frames[0]
    with torch.no_grad():
        out = learned.avatar.render(learned.table.params(frame.timestep_index), learned.data.capture.camera(frame),
                                    learned.background)
    foreground = out.rgb[out.alpha > 0.5].double()  # the avatar's own colours

    def between(changes):  # camera 0's colours minus camera 2's, per channel, over the avatar's colours
        seen = [foreground @ torch.as_tensor(changes[c]).double()[:, :3].T + torch.as_tensor(changes[c]).double()[:, 3]
                for c in ("cam00", "cam02")]
        return (seen[0] - seen[1]).mean(0).numpy()

    found, truth = between(learned.camera_colours.values()), between(TRUE_CHANGES)
    assert np.all(np.sign(found) == np.sign(truth)) or abs(truth[1]) < 0.05, (found, truth)
    assert np.corrcoef(found, truth)[0, 1] > 0.9 and np.linalg.norm(found - truth) < 0.5 * np.linalg.norm(truth), \
        (found, truth)


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """The fake run's avatar, its held-out camera's novel-view frames and their renders (unclamped)."""
    capture = Capture.open(tiny_capture(tmp_path_factory))
    run = RunFolder(fake_run(tmp_path_factory))
    avatar = run.load_avatar()
    frames = protocol_frames(capture, "novel_view", max_frames=6)
    source = TrackedParams(capture, run)
    renders = [render_np(avatar, source.params_for(f, f.camera_id), capture.camera(f)) for f in frames]
    return capture, run, frames, renders


KNOWN = np.array([[-0.15, 0.04, 0.0, 0.03], [0.02, -0.1, 0.05, -0.02], [0.0, 0.03, -0.2, 0.05]])  # [M − I | b]


def test_the_colour_fit_recovers_a_known_map_exactly(held_out):
    _, _, _, renders = held_out
    targets = [recolour(torch.from_numpy(rgb), torch.from_numpy(alpha), (1.0, 1.0, 1.0), KNOWN).numpy()
               for rgb, alpha in renders]
    change, info = fit_colour(renders, targets, (1.0, 1.0, 1.0))
    assert np.allclose(change, KNOWN, atol=1e-4), change
    assert info["kept"] and info["fit_l1_after"] < 0.1 * info["fit_l1_before"]
    assert info["fit_frames"] == len(renders) and info["fit_pixels"] > 100
    assert np.allclose(info["matrix"], np.eye(3) + KNOWN[:, :3], atol=1e-4)
    same, info = fit_colour(renders, [np.clip(rgb, 0, 1) for rgb, _ in renders], (1.0, 1.0, 1.0))
    assert np.abs(same).max() < 0.02  # nothing to fit: about the identity (clamped highlights aside)
    empty = [(rgb, np.zeros_like(alpha)) for rgb, alpha in renders]  # no foreground: nothing pins a map
    assert not fit_colour(empty, targets, (1.0, 1.0, 1.0))[0].any()
    with pytest.raises(ValueError):
        fit_colour([], [], (1.0, 1.0, 1.0))


def test_the_colour_aligned_protocol_scores_only_what_its_fit_never_saw(held_out, tmp_path, monkeypatch):
    """The held-out camera's images recoloured by a known map: the fit on one half finds it, the
    other half scores far above the unaligned novel view, and no scored image is loaded for the fit."""
    from mogaface.core.evaluate.evaluation import evaluate_run

    capture, run, frames, renders = held_out
    root = tmp_path / "capture"
    shutil.copytree(capture.root, root)
    for frame, (rgb, alpha) in zip(frames, renders):
        seen = recolour(torch.from_numpy(rgb), torch.from_numpy(alpha), (1.0, 1.0, 1.0), KNOWN)
        write_png(root / frame.file_path, seen.clamp(0, 1).numpy())
    loaded = watch_target_images(monkeypatch)
    result = evaluate_run(run.root, ["novel_view", "novel_view_colour_aligned"], 6, lpips=False,
                          out_dir=tmp_path / "eval", capture=root)
    fit, scored = split_frames(frames)
    seen = loaded[len(frames):len(frames) + len(fit)]  # after novel_view's: the fit's targets
    assert seen == [(f.camera_id, f.timestep_index) for f in fit]
    assert not set(seen) & {(f.camera_id, f.timestep_index) for f in scored}
    aligned = result["protocols"]["novel_view_colour_aligned"]
    assert [r["timestep"] for r in aligned["per_frame"]] == [f.timestep_index for f in scored]
    info = aligned["alignment"]["cam01"]
    assert info["kept"] and np.allclose(info["matrix"], np.eye(3) + KNOWN[:, :3], atol=0.03)
    unaligned = {r["timestep"]: r["psnr"] for r in result["protocols"]["novel_view"]["per_frame"]}
    for row in aligned["per_frame"]:
        assert row["psnr"] > unaligned[row["timestep"]] + 8, (row, unaligned)
    assert "| novel view colour aligned | 3 |" in (tmp_path / "eval" / "metrics.md").read_text()


def test_the_run_loader_gives_the_learned_colours_and_the_protocols_apply_them(held_out, tmp_path):
    """A training camera's views are scored (and rendered) in the colour the run learned for it;
    other cameras' as they are."""
    from mogaface.core.evaluate.render import render_run

    capture, run, _, _ = held_out
    root = tmp_path / "run"
    shutil.copytree(run.root, root)
    assert RunFolder(root).load_avatar().camera_colours is None
    (root / COLOURS_FILE).write_text(json.dumps({"cam00": {"matrix": (np.eye(3) + KNOWN[:, :3]).tolist(),
                                                           "offset": KNOWN[:, 3].tolist()}}))
    avatar = RunFolder(root).load_avatar()
    assert set(avatar.camera_colours) == {"cam00"} and np.allclose(avatar.camera_colours["cam00"], KNOWN)
    frames = protocol_frames(capture, "self_reenactment", max_frames=6)
    assert {"cam00", "cam01"} <= {f.camera_id for f in frames}  # a training camera and the held-out one
    source = TrackedParams(capture, RunFolder(root))
    plain = RunFolder(run.root).load_avatar()
    for a, b in zip(run_protocol(avatar, capture, source, frames, (1.0, 1.0, 1.0)),
                    run_protocol(plain, capture, source, frames, (1.0, 1.0, 1.0))):
        assert np.array_equal(a.prediction, b.prediction) == (a.frame.camera_id != "cam00"), a.frame
    coloured = render_run(root, [12], ["cam00", "cam02"], out_dir=tmp_path / "coloured")
    as_is = render_run(run.root, [12], ["cam00", "cam02"], out_dir=tmp_path / "as_is")
    assert [p.read_bytes() == q.read_bytes() for p, q in zip(coloured, as_is)] == [False, True]


def test_the_train_flag_turns_the_colours_on():
    import argparse

    from mogaface.core.cli import train as train_cli

    parser = argparse.ArgumentParser()
    train_cli.add_arguments(parser)
    assert train_cli._overrides(parser.parse_args(["cap", "--out", "run", "--camera-colour"]))["cameras"] == {
        "colour": True}
    assert "cameras" not in train_cli._overrides(parser.parse_args(["cap", "--out", "run"]))
    assert not C.TrainConfig().cameras.colour  # off by default, in every preset
    assert not any(C.resolve(name).cameras.colour for name in C.PRESETS)
