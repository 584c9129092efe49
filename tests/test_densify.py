"""Adaptive density control: binding inheritance, covered triangles, Adam rows, resets, schedules."""

import math

import torch

from mogaface.core.avatar.densify import (
    DensifySchedule,
    DensifyStrategy,
    keep_one_per_triangle,
    quaternion_to_matrix,
)
from mogaface.core.avatar.gaussians import PARAMETER_NAMES, BoundGaussians


def make_gaussians(n_faces=4, per_face=2, seed=0):
    torch.manual_seed(seed)
    g = BoundGaussians.one_per_triangle(n_faces, max_sh_degree=1)
    binding = torch.arange(n_faces).repeat_interleave(per_face)
    n = len(binding)
    rotation = torch.nn.functional.normalize(torch.randn(n, 4), dim=-1)
    return BoundGaussians(binding, 1, local_position=torch.randn(n, 3) * 0.1,
                          local_log_scale=torch.randn(n, 3) * 0.1 - 1, local_rotation=rotation,
                          opacity_logit=torch.randn(n), sh_dc=torch.randn(n, 1, 3), sh_rest=torch.randn(n, 3, 3)) \
        if per_face else g


def make_optimizer(g):
    groups = [{"params": [getattr(g, name)], "lr": 0.01, "name": name} for name in PARAMETER_NAMES]
    optimizer = torch.optim.Adam(groups, lr=0.0)
    loss = sum((getattr(g, name) ** 2).sum() for name in PARAMETER_NAMES)
    loss.backward()
    optimizer.step()
    optimizer.zero_grad()
    return optimizer


def schedule(**changes):
    base = dict(start=0, stop=1000, interval=10, grad_threshold=1e-3, percent_dense=0.5, split_count=2,
                min_opacity=0.005, max_screen_size=1000.0, max_world_size=100.0, opacity_reset_interval=0,
                max_gaussians=10000, sh_degree_interval=100, max_sh_degree=1)
    base.update(changes)
    return DensifySchedule(**base)


def observe_all(strategy, n, grad=1.0):
    radii = torch.full((n,), 3, dtype=torch.int32)
    strategy.observe(1, torch.full((n, 2), grad), radii, 2, 2)


def test_clone_and_split_inherit_binding_and_adam_rows_follow():
    g = make_gaussians(n_faces=4, per_face=2)
    # Gaussians 0..3 small (clone), 4..7 large (split) on a mesh of unit triangles.
    with torch.no_grad():
        g.local_log_scale[:4] = math.log(0.1)
        g.local_log_scale[4:] = math.log(0.5)
        g.opacity_logit[:] = 0.0
    optimizer = make_optimizer(g)
    old = {name: getattr(g, name).detach().clone() for name in ("binding", *PARAMETER_NAMES)}
    old_avg = optimizer.state[g.sh_dc]["exp_avg"].clone()
    n = len(g)
    strategy = DensifyStrategy(schedule(percent_dense=0.3), n, 4)
    observe_all(strategy, n)
    report = strategy.densify_and_prune(g, optimizer, torch.ones(4), 1.0, torch.Generator().manual_seed(0))
    assert report["cloned"] == 4 and report["split"] == 4
    assert len(g) == 8 + 4 + 8 - 4
    # Originals that were cloned stay first; then the clones; then the split children.
    assert torch.equal(g.binding[:4], old["binding"][:4])
    assert torch.equal(g.binding[4:8], old["binding"][:4])
    assert torch.equal(g.binding[8:], old["binding"][4:].repeat_interleave(2))
    assert torch.equal(g.sh_dc[4:8].detach(), old["sh_dc"][:4])
    children = g.local_log_scale[8:].detach()
    assert torch.allclose(children, old["local_log_scale"][4:].repeat_interleave(2, 0) - math.log(1.6))
    # Adam moments: kept rows keep theirs, new rows start at zero; the optimizer holds the new tensors.
    state = optimizer.state[g.sh_dc]
    assert state["exp_avg"].shape[0] == len(g)
    assert torch.equal(state["exp_avg"][:4], old_avg[:4])
    assert (state["exp_avg"][4:] == 0).all() and (state["exp_avg_sq"][4:] == 0).all()
    for group in optimizer.param_groups:
        assert group["params"][0] is getattr(g, group["name"])
    assert len(strategy.grad_accum) == len(g)


def test_split_children_lie_around_the_parent_in_its_frame():
    g = make_gaussians(n_faces=1, per_face=1)
    with torch.no_grad():
        g.local_log_scale[:] = torch.log(torch.tensor([[1.0, 1e-4, 1e-4]]))
    strategy = DensifyStrategy(schedule(split_count=4, percent_dense=0.01), 1, 1)
    observe_all(strategy, 1)
    strategy.densify_and_prune(g, None, torch.ones(1), 1.0, torch.Generator().manual_seed(1))
    offsets = g.local_position.detach() - make_gaussians(n_faces=1, per_face=1).local_position.detach()
    axis = quaternion_to_matrix(make_gaussians(n_faces=1, per_face=1).local_rotation.detach())[0, :, 0]
    # Spread along the parent's long axis only.
    along = offsets @ axis
    assert len(g) == 4 and torch.allclose(offsets, along[:, None] * axis, atol=1e-3)


def test_prune_never_empties_a_triangle():
    g = make_gaussians(n_faces=3, per_face=3)
    with torch.no_grad():
        g.opacity_logit[:] = -20.0  # all far below min_opacity
        g.opacity_logit[0] = -19.0  # the best of face 0
        g.opacity_logit[3:6] = 5.0  # face 1 is healthy
    optimizer = make_optimizer(g)
    strategy = DensifyStrategy(schedule(grad_threshold=1e9), len(g), 3)
    report = strategy.densify_and_prune(g, optimizer, torch.ones(3), 1.0, torch.Generator())
    assert sorted(g.binding.tolist()) == [0, 1, 1, 1, 2]
    assert abs(float(g.opacity_logit[0].detach()) + 19.0) < 0.1
    assert report["pruned"] == 4
    assert optimizer.state[g.opacity_logit]["exp_avg"].shape == (5,)


def test_keep_one_per_triangle_spares_the_best_scored():
    binding = torch.tensor([0, 0, 1, 1, 2])
    remove = torch.tensor([True, True, True, False, True])
    score = torch.tensor([0.1, 0.7, 0.9, 0.2, 0.0])
    kept = keep_one_per_triangle(remove, binding, score, 4)
    assert kept.tolist() == [True, False, True, False, False]


def test_budget_caps_growth_to_the_largest_gradients():
    g = make_gaussians(n_faces=4, per_face=2)
    strategy = DensifyStrategy(schedule(max_gaussians=11, percent_dense=10.0), len(g), 4)
    grads = torch.arange(8, dtype=torch.float32)[:, None].repeat(1, 2)
    strategy.observe(1, grads, torch.full((8,), 3, dtype=torch.int32), 2, 2)
    report = strategy.densify_and_prune(g, None, torch.ones(4), 1.0, torch.Generator())
    assert report["cloned"] == 3 and len(g) == 11
    assert torch.equal(g.binding[8:], g.binding[5:8])


def test_opacity_reset_clamps_and_forgets_moments():
    g = make_gaussians()
    optimizer = make_optimizer(g)
    with torch.no_grad():
        g.opacity_logit[0] = -10.0
    strategy = DensifyStrategy(schedule(start=1000, opacity_reset_interval=50, reset_opacity=0.01), len(g), 4)
    report = strategy.after_step(50, g, optimizer, torch.ones(4), 1.0, torch.Generator())
    assert report.get("opacity_reset")
    opacity = torch.sigmoid(g.opacity_logit.detach())
    assert (opacity <= 0.01 + 1e-6).all() and float(g.opacity_logit[0].detach()) == -10.0
    assert (optimizer.state[g.opacity_logit]["exp_avg"] == 0).all()
    assert strategy.resets_done == 1


def test_schedule_steps_and_sh_degree():
    s = schedule(start=100, stop=300, interval=50, opacity_reset_interval=200, sh_degree_interval=100,
                 max_sh_degree=3)
    assert [step for step in range(0, 400, 50) if s.densifies_at(step)] == [150, 200, 250, 300]
    assert [step for step in range(1, 1000) if s.resets_opacity_at(step)] == [200]
    assert [s.sh_degree(step) for step in (0, 99, 100, 250, 300, 10000)] == [0, 0, 1, 2, 3, 3]


def test_passes_between_are_the_latest_due_of_each_kind():
    s = schedule(start=300, stop=2000, interval=150, opacity_reset_interval=1200)
    for done in range(0, 2300, 7):
        for moved in (1, 2, 40, 151, 400, 1300):
            now = done + moved
            each = [[k for k in range(done + 1, now + 1) if is_due(k)] for is_due in (s.densifies_at, s.resets_opacity_at)]
            assert s.passes_between(done, now) == sorted({kind[-1] for kind in each if kind}), (done, now)
    assert [s.passes_between(k - 1, k) for k in (450, 451, 1200)] == [[450], [], [1200]]  # a step at a time


def test_state_dict_round_trip():
    strategy = DensifyStrategy(schedule(), 8, 4)
    observe_all(strategy, 8, grad=0.5)
    strategy.resets_done = 2
    other = DensifyStrategy(schedule(), 1, 4)
    other.load_state_dict(strategy.state_dict())
    assert torch.equal(other.grad_accum, strategy.grad_accum) and other.resets_done == 2


def test_observe_accumulates_exactly_what_the_visible_rows_give():
    """Whole-array updates equal gathering the visible rows (3DGS's NDC-scaled gradient norms)."""
    g = torch.Generator().manual_seed(5)
    n = 40
    strategy = DensifyStrategy(DensifySchedule(), n, 10)
    accum, count, radii_max = torch.zeros(n), torch.zeros(n), torch.zeros(n)
    for _ in range(3):
        grads = torch.randn(n, 2, generator=g)
        radii = torch.randint(0, 4, (n,), generator=g, dtype=torch.int32)
        grads[radii == 0] = float("nan")  # invisible rows' gradients must not leak in
        strategy.observe(1, grads, radii, 64, 48)
        visible = radii > 0
        accum[visible] += (grads[visible] * torch.tensor([32.0, 24.0])).norm(dim=-1)
        count[visible] += 1
        radii_max[visible] = torch.maximum(radii_max[visible], radii[visible].float())
    assert torch.equal(strategy.grad_accum, accum) and torch.equal(strategy.grad_count, count)
    assert torch.equal(strategy.max_radii, radii_max) and count.sum() > 0
