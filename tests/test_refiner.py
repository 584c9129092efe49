"""The multi-view refiner: its offsets have the asked scale, a pass is the weighted least-squares
solution (against numpy's), the full-size step's gradient and curvature are the derivatives of the
crops (against finite differences along other directions) and its step reads a small offset, a
refiner trained on rendered crops reads new offsets from full-size images, a step the views do not
support is refused, its file round-trips and refuses damaged or hostile files, and the command
writes a refiner that ``eval`` then uses."""

import json
import shutil

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import fake_run, tiny_capture

from mogaface.core.data.capture import Capture
from mogaface.core.errors import InputError
from mogaface.core.refiner.files import load_refiner, save_refiner
from mogaface.core.refiner.groups import GROUPS, add_offset, flatten, group_sizes, scale_vector
from mogaface.core.refiner.inference import refine
from mogaface.core.refiner.model import LinearRefiner
from mogaface.core.refiner.sampler import OffsetSampler
from mogaface.core.refiner.training import (
    DEFAULT_SPEC,
    RefinerSettings,
    _curvatures,
    _Run,
    frozen_avatar,
    train_refiner,
)
from mogaface.core.refiner.views import crop_cameras, full_size_gradient, posed, render_crop
from mogaface.core.run.folder import RunFolder

SMALL = {"grid": 8, "render_limit": 64, "prior": 1e-3, "gap_rank": 2}


@pytest.fixture(scope="module")
def run_root(tmp_path_factory):
    tiny_capture(tmp_path_factory)
    root = tmp_path_factory.mktemp("refined") / "run"
    shutil.copytree(fake_run(tmp_path_factory), root)
    return root


def test_sampler_offsets_have_the_asked_scale():
    n_expr = 10
    sampler = OffsetSampler(n_expr, width=2.0, seed=3)
    offsets = np.stack([sampler() for _ in range(4000)])
    magnitude_rms = np.sqrt((1.5 ** 3 - 0.3 ** 3) / (3 * 1.2))  # rms of a uniform [0.3, 1.5] magnitude
    at = 0
    for name, size in group_sizes(n_expr).items():
        expected = 2.0 * GROUPS[name][1] * magnitude_rms
        assert offsets[:, at:at + size].std() == pytest.approx(expected, rel=0.1), name
        at += size
    only = np.stack([OffsetSampler(n_expr, seed=4, groups=("translation",))() for _ in range(10)])
    assert np.all(only[:, :-3] == 0) and np.all(only[:, -3:] != 0)


def _random_refiner(n_expr: int, cameras=("a", "b", "c"), grid: int = 4, seed: int = 0, gap: float = 0.0,
                    rank: int = 2, curvature: float = 0.0):
    """Random matrices; ``curvature`` 0: never measured, so a pass takes no full-size step."""
    gen = torch.Generator().manual_seed(seed)
    count, features = len(scale_vector(n_expr)), 3 * grid * grid
    roots = torch.randn(len(cameras), count, count, generator=gen)
    return LinearRefiner({"grid": grid, "render_limit": 64, "n_expr": n_expr, "prior": 1e-6, "gap_rank": rank,
                          "full_size_steps": 1, "damping": 1e-3},
                         list(cameras), torch.randn(len(cameras), features, count, generator=gen),
                         torch.rand(len(cameras), features, generator=gen) + 0.5,
                         gap * torch.randn(len(cameras), features, generator=gen),
                         torch.rand(len(cameras), features, generator=gen),
                         gap * torch.randn(len(cameras), rank, features, generator=gen),
                         curvature * roots @ roots.transpose(1, 2))


def test_a_pass_is_the_weighted_least_squares_solution_over_the_views_it_is_given():
    n_expr = 4
    refiner = _random_refiner(n_expr, gap=0.3)
    scales = scale_vector(n_expr).numpy().astype(np.float64)
    truth = np.random.default_rng(1).normal(size=len(scales))
    views = ["c", "a"]  # any subset, any order
    idx = [refiner.camera_ids.index(c) for c in views]
    forward = refiner.forward.numpy()
    features = np.stack([forward[i] @ truth + refiner.gap_mean.numpy()[i] for i in idx])
    solved = refiner.offset(torch.as_tensor(features), views)
    np.testing.assert_allclose(solved / scales, truth, rtol=1e-4, atol=1e-5)  # noise-free: the exact offset
    noisy = features + np.random.default_rng(2).normal(size=features.shape)
    # the reference: whiten each view by the Cholesky factor of its full noise covariance, then lstsq
    design, target = [], []
    for k, i in enumerate(idx):
        basis = refiner.gap_basis.numpy()[i]
        covariance = np.diag(refiner.residual.numpy()[i] + refiner.gap_var.numpy()[i]) + basis.T @ basis
        whiten = np.linalg.inv(np.linalg.cholesky(covariance))
        design.append(whiten @ forward[i])
        target.append(whiten @ (noisy[k] - refiner.gap_mean.numpy()[i]))
    reference = np.linalg.lstsq(np.concatenate(design), np.concatenate(target), rcond=None)[0]
    np.testing.assert_allclose(refiner.offset(torch.as_tensor(noisy), views) / scales, reference, rtol=1e-3, atol=1e-4)
    diagonal_only = _random_refiner(n_expr, gap=0.3, rank=0)  # same draws up to the basis: another answer
    assert not np.allclose(diagonal_only.offset(torch.as_tensor(noisy), views), refiner.offset(torch.as_tensor(noisy), views))
    with pytest.raises(InputError, match="'z'"):
        refiner.offset(torch.as_tensor(features[:1]), ["z"])


def _group_slice(name: str, n_expr: int) -> slice:
    at = 0
    for group, size in group_sizes(n_expr).items():
        if group == name:
            return slice(at, at + size)
        at += size
    raise KeyError(name)


def _full_size_frame(run_root, seed=0):
    """The avatar, its run, one timestep's crops (every camera) at the tracked parameters, and the
    avatar's own renders there at a small known translation offset (the observation)."""
    avatar = frozen_avatar(run_root)
    folder = RunFolder(run_root)
    capture = Capture.open(folder.capture_root)
    run = _Run(folder, capture)
    n_expr = avatar.flame.n_expr
    t = run.timesteps[0]
    start = run.params[t]
    offset = OffsetSampler(n_expr, width=1.0, seed=seed, groups=("translation",))()
    crops = crop_cameras([run.cameras.at(c, t) for c in run.camera_ids], posed(avatar, start).vertices, 64)
    observed = [render_crop(posed(avatar, add_offset(start, offset, n_expr)), crop, run.background) for crop in crops]
    return avatar, run, t, start, offset, crops, observed


def _crop_loss(avatar, params, crops, observed, background) -> float:
    """What the full-size gradient descends, rendered without autograd: Σ_v ‖o_v − r_v‖² / (2·pixels_v)."""
    head = posed(avatar, params)
    return sum(float(((render_crop(head, crop, background) - seen) ** 2).sum()) / (2 * crop[1].width ** 2)
               for crop, seen in zip(crops, observed))


def test_the_full_size_gradient_and_curvature_are_the_crops_derivatives(run_root):
    """Against central differences along random directions (the curvature was measured by forward
    differences along each regressed value, the gradient by autograd): ``−gᵀu`` is the loss's slope
    along ``u`` and ``uᵀHu`` the mean squared change of the crops' pixels. The tolerance is wide
    (the tiny head's float32 renders scatter); a lost scale, pixel count or sign is far outside it."""
    avatar, run, t, start, _, crops, observed = _full_size_frame(run_root)
    n_expr = avatar.flame.n_expr
    gradient = full_size_gradient(avatar, start, crops, observed, run.background, n_expr).numpy()
    run.timesteps = [t]  # the curvature at this frame alone
    spec = {"render_limit": 64, "full_size_steps": 1, "n_expr": n_expr}
    curvature = _curvatures(avatar, run, RefinerSettings(curvature_timesteps=1), spec, np.random.default_rng(0),
                            lambda *a, **k: None, lambda: False).numpy()
    scales = scale_vector(n_expr).numpy()
    rng = np.random.default_rng(4)
    eps = 0.2  # smaller steps amplify the float32 renders' noise in the squared change
    for name in ("translation", "rotation"):  # the groups a 48 px head shows clearly
        u = np.zeros(len(scales))
        u[_group_slice(name, n_expr)] = rng.normal(size=3)
        plus, minus = (add_offset(start, (sign * eps * u * scales).astype(np.float32), n_expr) for sign in (1, -1))
        slope = (_crop_loss(avatar, plus, crops, observed, run.background)
                 - _crop_loss(avatar, minus, crops, observed, run.background)) / (2 * eps)
        assert -gradient @ u == pytest.approx(slope, rel=0.3), name  # float32 renders: differences scatter ±15 %
        if name != "translation":  # at 48 px a rotation this small is sub-pixel: its squared change is noise
            continue
        measured = sum(float(u @ curvature[i] @ u) for i in range(len(crops)))
        change = sum(float((((render_crop(posed(avatar, plus), crop, run.background)
                              - render_crop(posed(avatar, minus), crop, run.background)) / (2 * eps)) ** 2).sum())
                     / crop[1].width ** 2 for crop in crops)
        assert measured == pytest.approx(change, rel=0.3), name


def test_one_full_size_step_reads_a_small_offset_from_the_crops(run_root):
    """The avatar's own crops at a tracker-sized translation offset: one damped Gauss–Newton step
    with the measured curvature takes most of it out."""
    avatar, run, t, start, offset, crops, observed = _full_size_frame(run_root, seed=2)
    n_expr = avatar.flame.n_expr
    refiner = _random_refiner(n_expr, cameras=run.camera_ids)
    refiner.spec["damping"] = DEFAULT_SPEC["damping"]
    refiner.curvature = _curvatures(avatar, run, RefinerSettings(curvature_timesteps=3),
                                    {"render_limit": 64, "full_size_steps": 1, "n_expr": n_expr},
                                    np.random.default_rng(0), lambda *a, **k: None, lambda: False)
    gradient = full_size_gradient(avatar, start, crops, observed, run.background, n_expr)
    step = refiner.full_size_offset(gradient, run.camera_ids)
    left = (step - offset)[_group_slice("translation", n_expr)]
    assert np.linalg.norm(left) < 0.35 * np.linalg.norm(offset), (left, offset[_group_slice("translation", n_expr)])


def _known_offsets(avatar, capture, refiner, width, count=6, seed=11, groups=None):
    """Full-size renders of the avatar at the tracked parameters plus known offsets (every camera
    of the timestep), and per group the RMS error (in the group's scale) of one refiner pass and
    of predicting no offset."""
    rng = np.random.default_rng(seed)
    n_expr = refiner.spec["n_expr"]
    scales = scale_vector(n_expr).numpy()
    sampler = OffsetSampler(n_expr, width=width, seed=seed, groups=groups)
    errors, zeros = [], []
    for _ in range(count):
        t = int(rng.choice(capture.timesteps))
        cameras = [capture.camera_at(c, t) for c in sorted(capture.cameras)]
        start = capture.flame_params(t)
        offset = sampler()
        truth = add_offset(start, offset, n_expr)
        with torch.no_grad():
            images = [avatar.render_posed(posed(avatar, truth).vertices, c, (1.0, 1.0, 1.0)).rgb.numpy() for c in cameras]
        refined = refine(avatar, refiner, start, cameras, images, (1.0, 1.0, 1.0), passes=1)[0]
        errors.append((flatten(refined, n_expr) - flatten(truth, n_expr)) / scales)
        zeros.append(offset / scales)
    out = {}
    at = 0
    for name, size in group_sizes(n_expr).items():
        out[name] = (float(np.sqrt(np.mean(np.square(np.stack(errors)[:, at:at + size])))),
                     float(np.sqrt(np.mean(np.square(np.stack(zeros)[:, at:at + size])))))
        at += size
    return out


def test_a_refiner_trained_on_rendered_offsets_reads_new_ones_from_full_size_images(run_root, tmp_path):
    """Training renders crops, the test renders whole views and cuts them: the same windows are
    compared as in use. At 48 px a tracker-sized offset is a fraction of a pixel, so this tiny
    check perturbs the head's translation alone, four times wider than a tracker's error. The
    observations are renders, so no capture gap is measured (the fake run's avatar was never fitted
    to its captures: its gap is its whole image)."""
    width = 4.0
    settings = RefinerSettings(starts=12, offsets_per_start=4, gap_timesteps=0, seed=0, threads=1,
                               offset_width=width, offset_groups=("translation",), spec=SMALL)
    events = []
    result = train_refiner(run_root, settings, out=tmp_path / "refiner.pt", listeners=[events.append])
    assert events[0]["event"] == "start" and events[-1]["event"] == "done"
    assert {e.get("stage") for e in events if e["event"] == "iter"} == {"offsets", "curvature"}
    assert result["samples_per_camera"] == 48 and (tmp_path / "refiner.pt").exists()
    avatar = frozen_avatar(run_root)
    capture = Capture.open(RunFolder(run_root).capture_root)
    refiner, trained = load_refiner(tmp_path / "refiner.pt", avatar.flame.n_expr)
    assert trained["explained"] > 0.5 and refiner.camera_ids == ["cam00", "cam01", "cam02"]
    error, zero = _known_offsets(avatar, capture, refiner, width, groups=("translation",))["translation"]
    assert error < 0.25 * zero, (error, zero)  # 0.30 against 4.2 at this seed


def _nonsense_frame(run_root):
    """The avatar, a refiner that answers nonsense (random matrices, huge steps) with every answer
    recorded, and a frame whose views are the avatar's own renders at the start."""
    avatar = frozen_avatar(run_root)
    capture = Capture.open(RunFolder(run_root).capture_root)
    refiner = _random_refiner(avatar.flame.n_expr, cameras=sorted(capture.cameras), seed=5, gap=0.3)
    refiner.forward = refiner.forward * 1e-2  # a made-up gap read through tiny changes: huge steps
    answers = []
    solve = refiner.offset
    refiner.offset = lambda *args: answers.append(solve(*args)) or answers[-1]
    t = capture.timesteps[0]
    cameras = [capture.camera_at(c, t) for c in sorted(capture.cameras)]
    start = capture.flame_params(t)
    with torch.no_grad():
        images = [avatar.render_posed(posed(avatar, start).vertices, c, (1.0, 1.0, 1.0)).rgb.numpy() for c in cameras]
    return avatar, refiner, answers, start, cameras, images


def test_a_pass_the_views_do_not_support_is_not_taken(run_root):
    """A refiner that answers nonsense (random matrices) cannot make the input views worse: its
    steps are refused and the start comes back."""
    avatar, refiner, answers, start, cameras, images = _nonsense_frame(run_root)
    n_expr = avatar.flame.n_expr
    history = refine(avatar, refiner, start, cameras, images, (1.0, 1.0, 1.0), passes=2)
    assert len(history) == 2 and len(answers) == 1  # refused once: the second pass would ask the same
    assert np.abs(answers[0] / refiner.scales.numpy()).max() > 3.0  # it did answer nonsense
    for params in history:
        np.testing.assert_array_equal(flatten(params, n_expr), flatten(start, n_expr))


def test_a_single_pass_renders_each_view_once_and_takes_the_solve(run_root, monkeypatch):
    """One pass is not checked (its check would double its time): every view is rendered once, at
    the start, and the solve comes back as it is, even a refiner's nonsense; a second pass checks
    the first (the test above)."""
    import mogaface.core.refiner.views as views

    avatar, refiner, answers, start, cameras, images = _nonsense_frame(run_root)
    n_expr = avatar.flame.n_expr
    renders = []
    render_world = views.render_world
    monkeypatch.setattr(views, "render_world", lambda *args: renders.append(args[1]) or render_world(*args))
    (single,) = refine(avatar, refiner, start, cameras, images, (1.0, 1.0, 1.0), passes=1)
    assert len(renders) == len(cameras) and len(answers) == 1
    np.testing.assert_allclose(flatten(single, n_expr), flatten(start, n_expr) + answers[0], rtol=1e-5, atol=1e-6)


def test_the_refiner_renders_a_modulated_avatar_with_its_texture_attention(run_root):
    """A MoGaFace run's avatar changes its Gaussians with the parameters (texture attention): the
    refiner's renders are the avatar's own ``render`` at those parameters, not the bare Gaussians'."""
    from mogaface.core.avatar.avatar import flame_params_to_torch
    from mogaface.core.correction.avatar import ModulatedAvatar
    from mogaface.core.correction.model import MoGaFace
    from mogaface.core.refiner.crops import crop_camera, head_window
    from mogaface.core.refiner.views import render_crop

    avatar = frozen_avatar(run_root)
    capture = Capture.open(RunFolder(run_root).capture_root)
    spec = {"mode": "multi", "bank": False, "texture": True, "input_size": 32, "feature_dim": 16,
            "encoder_width": 4, "heads": 2, "hidden": 16, "plane_size": 8, "plane_dim": 4, "texture_hidden": 8,
            "n_expr": avatar.flame.n_expr}
    torch.manual_seed(0)
    model = MoGaFace(spec, capture.timesteps, sorted(capture.cameras), avatar.posed_vertices(
        flame_params_to_torch(capture.flame_params(capture.timesteps[0]))))
    with torch.no_grad():
        for head in model.texture.heads.values():
            head.weight.normal_(0.0, 0.5)
    modulated = ModulatedAvatar(avatar, model)
    t = capture.timesteps[0]
    params = capture.flame_params(t)
    camera = capture.camera_at(sorted(capture.cameras)[0], t)
    head = posed(modulated, params)
    window = head_window(camera, head.vertices.numpy())
    crop = (window, crop_camera(camera, window, 40))
    with torch.no_grad():
        own = modulated.render(flame_params_to_torch(params), crop[1], (1.0, 1.0, 1.0)).rgb.clamp(0, 1).permute(2, 0, 1)
        bare = render_crop(posed(avatar, params), crop, (1.0, 1.0, 1.0))
    torch.testing.assert_close(render_crop(head, crop, (1.0, 1.0, 1.0)), own)
    assert (own - bare).abs().max() > 0.05  # the texture attention does change this render


def test_refiner_file_round_trip(tmp_path):
    refiner = _random_refiner(5, gap=0.2, curvature=1.0)
    save_refiner(refiner, tmp_path / "refiner.pt", {"samples_per_camera": 7})
    assert [p.name for p in tmp_path.iterdir()] == ["refiner.pt"]  # no temporary file left
    loaded, trained = load_refiner(tmp_path / "refiner.pt", n_expr=5)
    assert trained == {"samples_per_camera": 7} and loaded.spec == refiner.spec
    assert loaded.camera_ids == refiner.camera_ids
    features = torch.rand(2, 48, dtype=torch.float64)
    np.testing.assert_allclose(loaded.offset(features, ["b", "c"]), refiner.offset(features, ["b", "c"]), rtol=1e-4)
    gradient = torch.rand(len(refiner.scales), dtype=torch.float64)
    np.testing.assert_allclose(loaded.full_size_offset(gradient, ["a"]), refiner.full_size_offset(gradient, ["a"]),
                               rtol=1e-4)

class _Hostile:
    def __reduce__(self):
        return (print, ("executed",))


@pytest.mark.parametrize("damage, field", [
    (lambda s: b"not a torch file", None),
    (lambda s: {**s, "format": "mogaface-modules"}, "format"),
    (lambda s: {**s, "version": 1}, "version"),  # the earlier convolutional refiner
    (lambda s: {**s, "version": 2}, "train-refiner"),  # no curvature yet: train it again
    (lambda s: {**s, "spec": {**s["spec"], "full_size_steps": -1}}, "spec.full_size_steps"),
    (lambda s: {**s, "spec": {**s["spec"], "damping": 0.0}}, "spec.damping"),
    (lambda s: {**s, "state": {**s["state"], "curvature": -s["state"]["curvature"]}}, "state.curvature"),
    (lambda s: {**s, "state": {**s["state"], "curvature": s["state"]["curvature"][:, :3]}}, "state.curvature"),
    (lambda s: {**s, "spec": {**s["spec"], "grid": "four"}}, "spec.grid"),
    (lambda s: {**s, "spec": {**s["spec"], "prior": float("nan")}}, "spec.prior"),
    (lambda s: {**s, "spec": {**s["spec"], "n_expr": 6}}, "spec.n_expr"),
    (lambda s: {**s, "cameras": ["a", "a", "b"]}, "cameras"),
    (lambda s: {**s, "state": {**s["state"], "forward": s["state"]["forward"] * np.nan}}, "state.forward"),
    (lambda s: {**s, "state": {**s["state"], "residual": -s["state"]["residual"]}}, "state.residual"),
    (lambda s: {**s, "state": {**s["state"], "gap_mean": s["state"]["gap_mean"][:2]}}, "state.gap_mean"),
    (lambda s: {**s, "state": {k: v for k, v in s["state"].items() if k != "gap_var"}}, "state.gap_var"),
    (lambda s: {**s, "spec": {**s["spec"], "gap_rank": 3}}, "state.gap_basis"),
    (lambda s: {**s, "state": {**s["state"], "extra": torch.zeros(1)}}, "state.extra"),
    (lambda s: {**s, "payload": _Hostile()}, None),
])
def test_a_damaged_or_hostile_refiner_file_is_a_clear_error(tmp_path, damage, field):
    path = tmp_path / "refiner.pt"
    save_refiner(_random_refiner(5, curvature=1.0), path)
    state = damage(torch.load(path, weights_only=True))
    if isinstance(state, bytes):
        path.write_bytes(state)
    else:
        torch.save(state, path)
    with pytest.raises(InputError) as error:
        load_refiner(path, n_expr=5)
    assert "refiner.pt" in str(error.value)
    if field is not None:
        assert field in str(error.value)


def test_the_command_trains_a_refiner_that_eval_then_uses(run_root, tmp_path, capsys):
    from mogaface.core.cli import main
    from mogaface.core.evaluate.evaluation import evaluate_run

    run = tmp_path / "run"
    shutil.copytree(run_root, run, ignore=shutil.ignore_patterns("refiner.pt"))
    assert main(["train-refiner", str(run), "--starts", "2", "--offsets-per-start", "2", "--gap-timesteps", "2",
                 "--curvature-timesteps", "1", "--threads", "1", "--quiet", "--events", "stdout"]) == 0
    assert '"event": "done"' in capsys.readouterr().out
    refiner, trained = load_refiner(run / "refiner.pt")
    assert trained["gap_cameras"] == ["cam00", "cam02"]  # the held-out camera's captures are never read
    assert refiner.full_size_steps(refiner.camera_ids) == DEFAULT_SPEC["full_size_steps"]  # curvature measured
    assert all(bool(refiner.curvature[i].diagonal().gt(0).all()) for i in range(len(refiner.camera_ids)))
    result = evaluate_run(run, ["self_reenactment"], 1, lpips=False, out_dir=tmp_path / "eval")
    assert result["inference"].startswith("multi-view refiner")
    assert main(["train-refiner", str(tmp_path / "missing")]) == 2


@pytest.mark.benchmark
def test_the_benchmark_compares_a_refiner_with_fitting_and_the_search_chooses_on_validation_frames(
        run_root, tmp_path, capsys, monkeypatch):
    from mogaface.core.cli import main

    run = tmp_path / "run"
    shutil.copytree(run_root, run, ignore=shutil.ignore_patterns("refiner.pt"))
    train_refiner(run, RefinerSettings(starts=2, offsets_per_start=2, gap_timesteps=2, curvature_timesteps=1,
                                       threads=1))

    # the benchmark of that refiner against fitting of every asked length
    out = tmp_path / "bench.json"
    assert main(["bench", "refiner", "--avatar", str(run), "--quick", "--threads", "1",
                 "--fit-steps", "1,3", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert {"fit_1", "fit_3", "refined_1", "refined_3", "refined_fit_1"} <= set(report["psnr_db"])
    assert set(report["fitting_time_over_refiner"]) == {"fit_1/refined_1", "fit_1/refined_3", "fit_3/refined_1",
                                                        "fit_3/refined_3"}
    seconds = report["seconds_per_frame"]
    for steps in (1, 3):
        ratio = report["fitting_time_over_refiner"][f"fit_{steps}/refined_1"]
        assert ratio == pytest.approx(seconds[f"fit_{steps}"] / seconds["refined_1"], rel=0.05, abs=0.02)
    # what was scored, by name; the same views read by the refiner and fitting; time at equal quality
    assert report["scored"]["label"].startswith("self-reenactment") and "FREE" in report["scored"]["label"]
    assert len(report["scored"]["frames"]) == report["frames"] == 4
    assert report["warm_up_frame"] not in report["scored"]["frames"]
    reads = report["input_views"]
    assert len(reads["fit_1"]) == len(reads["refined_1"]) == 4 and reads["fit_1"] == reads["refined_1"]
    assert all(entry["scored"] not in entry["read"] and "cam01" not in entry["read"] for entry in reads["fit_1"])
    for passes in (1, 3):
        equal = report["equal_quality"][f"refined_{passes}"]
        assert equal["status"] in ("interpolated", "not reached", "reached by the shortest")
        assert (equal["fit_steps"] is None) == (equal["status"] == "not reached")
    # parameter errors raw and in the avatar's gauge for every source; the truth and the ceiling
    errors = report["parameter_errors_mm"]
    assert {"tracked", "refined_1", "fit_1", "true", "true_gauge"} <= set(errors)
    assert all(set(e) == {"vertex_mm", "expr_vertex_mm", "vertex_mm_gauge", "expr_vertex_mm_gauge"}
               for e in errors.values())
    assert errors["true"]["vertex_mm"] == errors["true_gauge"]["vertex_mm_gauge"] == 0.0
    assert errors["true_gauge"]["vertex_mm"] == pytest.approx(errors["true"]["vertex_mm_gauge"], abs=1e-3)
    assert errors["true_gauge"]["vertex_mm"] > 0  # the fine-tuned run's gauge is not the raw truth

    # several runs: each report kept in its run folder and reused, and the table over them
    second = tmp_path / "run2"
    shutil.copytree(run, second)
    table = tmp_path / "table.json"
    assert main(["bench", "refiner", "--avatar", f"{run},{second}", "--quick", "--threads", "1",
                 "--fit-steps", "1,3", "--out", str(table)]) == 0
    kept = json.loads((second / "bench_refiner.json").read_text())["report"]
    assert kept["run"] == str(second)
    markdown = table.with_suffix(".md").read_text()
    assert "2 runs" in markdown and "refiner, 1 pass" in markdown and "mesh mm, gauge" in markdown
    edited = {**kept, "psnr_db": {**kept["psnr_db"], "refined_1": 99.0}}
    (second / "bench_refiner.json").write_text(json.dumps({**json.loads((second / "bench_refiner.json").read_text()),
                                                           "report": edited}))
    assert main(["bench", "refiner", "--avatar", f"{run},{second}", "--quick", "--threads", "1",
                 "--fit-steps", "1,3", "--out", str(table)]) == 0
    assert json.loads(table.read_text())["runs"][1]["psnr_db"]["refined_1"] == 99.0  # reused, not recomputed
    from mogaface.bench.refiner import cached_report

    again = cached_report(RunFolder(second), 1, True, (1,), "test")  # other options: measured again
    assert again["psnr_db"]["refined_1"] != 99.0

    with pytest.raises(SystemExit):
        main(["bench", "refiner", "--fit-steps", "10,x"])
    assert "positive step counts" in capsys.readouterr().err
    assert main(["bench", "train", "--fit-steps", "10"]) == 2
    assert "refiner benchmark only" in capsys.readouterr().err

    # settings chosen on the validation frames, every try written; the test frames refused
    import mogaface.bench.refiner_search as search

    monkeypatch.setattr(search, "REFINER_GRID", {"prior": (1e-3, 1e3), "gap_rank": (0,)})
    monkeypatch.setattr(search, "FIT_GRID", {"prior_weight": (0.0,)})
    monkeypatch.setattr(search, "FIT_SEARCH_STEPS", 1)
    out = tmp_path / "search.json"
    assert main(["bench", "refiner_search", "--avatar", str(run), "--quick", "--threads", "1", "--out", str(out)]) == 0
    searched = json.loads(out.read_text())
    assert searched["split"] == "validation" and all("VAL" in s["label"] for s in searched["scored"])
    assert all("FREE" not in frame for s in searched["scored"] for frame in s["frames"])
    tried = searched["refiner"]["tried"]
    assert len({json.dumps(t["settings"], sort_keys=True) for t in tried}) == len(tried) >= 3
    assert searched["refiner"]["chosen_psnr_db"] == max(t["psnr_db"] for t in tried
                                                        if t["settings"] == searched["refiner"]["chosen"])
    assert {"vertex_mm_gauge", "expr_vertex_mm_gauge"} <= set(tried[0]["mean"])
    assert len(searched["fitting"]["tried"]) == 2
    capsys.readouterr()
    assert main(["bench", "refiner_search", "--avatar", str(run), "--split", "test"]) == 2
    assert "validation frames only" in capsys.readouterr().err


@pytest.mark.benchmark
def test_the_training_search_trains_a_refiner_per_try_on_validation_frames_and_reuses_them(run_root, tmp_path,
                                                                                           monkeypatch):
    import mogaface.bench.refiner_training_search as search
    from mogaface.core.cli import main

    run = tmp_path / "run"
    shutil.copytree(run_root, run, ignore=shutil.ignore_patterns("refiner.pt"))  # a run without its own refiner
    monkeypatch.setattr(search, "TRAINING_GRID", {"grid": (4,), "offsets_per_start": (1,)})
    out = tmp_path / "search.json"
    assert main(["bench", "refiner_training_search", "--avatar", str(run), "--quick", "--threads", "1",
                 "--out", str(out)]) == 0
    found = json.loads(out.read_text())
    tried = found["training"]["tried"]
    assert [t["settings"] for t in tried] == [{"grid": 16, "offsets_per_start": 4}, {"grid": 4, "offsets_per_start": 4},
                                              {"grid": 16, "offsets_per_start": 1}]
    assert all("VAL" in s["label"] for s in found["scored"]) and not (run / "refiner.pt").exists()
    trained = sorted(p.name for p in (run / search.TRIES_DIR).glob("*.pt"))
    assert len(trained) == 3 and all(name.endswith("_quick.pt") for name in trained)
    times = {p: p.stat().st_mtime_ns for p in (run / search.TRIES_DIR).glob("*.pt")}
    assert main(["bench", "refiner_training_search", "--avatar", str(run), "--quick", "--threads", "1",
                 "--out", str(out)]) == 0
    assert all(t["reused"] for t in json.loads(out.read_text())["training"]["tried"])
    assert {p: p.stat().st_mtime_ns for p in (run / search.TRIES_DIR).glob("*.pt")} == times
    assert main(["bench", "refiner_training_search", "--avatar", str(run), "--split", "test"]) == 2
