"""The fixed-budget densification: stacked copies that render what their parent did, relocation of
dead Gaussians, growth to the budget, the noise on faint ones, and the strategy in a training run."""

import math

import pytest
import torch
from test_densify import make_gaussians, make_optimizer, schedule
from test_train_run import final_tensors, read_events, tiny_capture, tiny_config  # noqa: F401 - a fixture

from mogaface.core.avatar.gaussians import PARAMETER_NAMES
from mogaface.core.avatar.mcmc import MCMCStrategy, stacked_equivalent
from mogaface.core.errors import InputError
from mogaface.core.train import config as C


@pytest.mark.parametrize("opacity,count", [(0.3, 2), (0.9, 3), (0.05, 7), (0.99, 30), (0.6, 51)])
def test_stacked_copies_render_what_the_parent_did(opacity, count):
    """Against a quadrature of the footprint (1D, as the formula is): the stack's alpha at the
    centre is the parent's opacity, and its integral over the footprint is the parent's."""
    new_opacity, factor = stacked_equivalent(torch.tensor([opacity]), torch.tensor([count]))
    x = torch.linspace(-12.0, 12.0, 200_001, dtype=torch.float64)
    parent = opacity * torch.exp(-0.5 * x ** 2)
    stack = 1.0 - (1.0 - float(new_opacity) * torch.exp(-0.5 * (x / float(factor)) ** 2)) ** count
    assert float(stack[len(x) // 2]) == pytest.approx(opacity, rel=1e-5)
    assert float(torch.trapezoid(stack, x)) == pytest.approx(float(torch.trapezoid(parent, x)), rel=1e-4)
    assert float(factor) < 1.0  # each copy is narrower than its parent


def test_one_copy_is_the_parent_itself():
    opacity = torch.tensor([0.01, 0.5, 0.97])
    new_opacity, factor = stacked_equivalent(opacity, torch.ones(3, dtype=torch.long))
    assert torch.allclose(new_opacity, opacity) and torch.allclose(factor, torch.ones(3))


def mcmc_gaussians(dead_rows, n_faces=4, per_face=3):
    g = make_gaussians(n_faces=n_faces, per_face=per_face)
    with torch.no_grad():
        g.opacity_logit[:] = 2.0
        g.opacity_logit[dead_rows] = -12.0  # far below the dead line
    return g


def test_relocation_moves_the_dead_onto_live_ones_and_forgets_their_moments():
    g = mcmc_gaussians([0, 1, 4, 9])  # rows 0, 1 of face 0; row 4 of face 1; row 9 of face 3
    optimizer = make_optimizer(g)
    live_before = {name: getattr(g, name).detach()[[2, 3, 5, 6, 7, 8, 10, 11]].clone()
                   for name in ("binding", "local_position", "sh_dc")}
    strategy = MCMCStrategy(schedule(), len(g), 4)
    moved = strategy.relocate(g, optimizer, torch.Generator().manual_seed(0))
    assert moved == 4 and len(g) == 12
    opacity = torch.sigmoid(g.opacity_logit.detach())
    assert bool((opacity > 0.005).all())
    # The live rows kept their order and their places; the moved ones sit on a live one's triangle
    # and position, as copies of it.
    for name, before in live_before.items():
        assert torch.equal(getattr(g, name).detach()[:8], before), name
    for row in range(8, 12):
        same = (g.local_position.detach()[:8] == g.local_position.detach()[row]).all(-1)
        assert same.any() and g.binding[row] == g.binding[:8][same][0]
    # Each source and its copies are a stack: the sources' and copies' opacity moments start over.
    for name in PARAMETER_NAMES:
        assert not optimizer.state[getattr(g, name)]["exp_avg"][8:].any(), name
    sources = [i for i in range(8) if bool((g.local_position.detach()[8:] == g.local_position.detach()[i]).all(-1).any())]
    assert not optimizer.state[g.opacity_logit]["exp_avg"][sources].any()
    untouched = [i for i in range(8) if i not in sources]
    assert optimizer.state[g.opacity_logit]["exp_avg"][untouched].all()


def test_a_triangle_keeps_its_last_gaussian_dead_or_not():
    g = mcmc_gaussians([3, 4, 5])  # every Gaussian of face 1
    strategy = MCMCStrategy(schedule(), len(g), 4)
    assert strategy.relocate(g, make_optimizer(g), torch.Generator().manual_seed(1)) == 2
    assert int((g.binding == 1).sum()) == 1


def test_growth_adds_a_share_up_to_the_budget():
    g = mcmc_gaussians([], n_faces=10, per_face=4)  # 40
    strategy = MCMCStrategy(schedule(max_gaussians=47), len(g), 10)
    generator = torch.Generator().manual_seed(2)
    optimizer = make_optimizer(g)  # (one Adam step on every row alike)
    opacity = float(torch.sigmoid(g.opacity_logit.detach()[0]))  # all alike
    assert strategy.grow(g, optimizer, generator, 1.1) == 4 and len(g) == 44
    # the parents share their opacity with their copies: each stack composites to the parent's
    stacked = torch.sigmoid(g.opacity_logit.detach())
    assert float(stacked.min()) < opacity and float(stacked[40:].max()) < opacity
    positions = g.local_position.detach()
    for row in range(40, 44):  # a stack: the source and its copies, at one position
        n = int((positions == positions[row]).all(-1).sum())
        assert float(1 - (1 - stacked[row]) ** n) == pytest.approx(opacity, rel=1e-5)
    assert strategy.grow(g, None, generator, 1.1) == 3 and len(g) == 47
    assert strategy.grow(g, None, generator, 1.1) == 0 and len(g) == 47


def test_a_pass_relocates_then_grows_on_its_schedule():
    g = mcmc_gaussians([0, 7])
    strategy = MCMCStrategy(schedule(interval=10, growth=1.25), len(g), 4)
    generator = torch.Generator().manual_seed(3)
    assert strategy.after_step(9, g, None, torch.ones(4), 1.0, generator) == {}
    assert strategy.after_step(10, g, None, torch.ones(4), 1.0, generator) == {"relocated": 2, "added": 3,
                                                                               "gaussians": 15}


def test_by_default_the_budget_is_reached_at_the_last_pass():
    g = mcmc_gaussians([], n_faces=10, per_face=4)  # 40
    strategy = MCMCStrategy(schedule(start=0, stop=50, interval=10, max_gaussians=400), len(g), 10)
    counts = [strategy.after_step(step, g, None, torch.ones(10), 1.0, torch.Generator().manual_seed(step))["gaussians"]
              for step in (10, 20, 30, 40, 50)]
    assert counts[-1] == 400 and all(b / a == pytest.approx(10 ** 0.2, abs=0.06) for a, b in zip([40, *counts], counts))


def test_noise_moves_the_faint_along_their_axes_and_leaves_the_opaque():
    g = mcmc_gaussians([0, 5])
    before = g.local_position.detach().clone()
    strategy = MCMCStrategy(schedule(noise=0.5), len(g), 4)
    strategy.perturb(g, 1.0, torch.Generator().manual_seed(4))
    moved = (g.local_position.detach() - before).norm(dim=-1)
    assert bool((moved[[0, 5]] > 1e-3).all())
    assert float(moved[[i for i in range(12) if i not in (0, 5)]].max()) < 1e-12
    # the same draw, half the rate: half the step
    again = mcmc_gaussians([0, 5])
    strategy.perturb(again, 0.5, torch.Generator().manual_seed(4))
    assert torch.allclose((again.local_position.detach() - before)[0], (g.local_position.detach() - before)[0] / 2)


def test_an_unknown_strategy_is_refused():
    with pytest.raises(InputError, match="densify.strategy"):
        C.resolve(overrides={"densify": {"strategy": "gsplat"}})
    with pytest.raises(InputError, match="densify.growth"):
        C.resolve(overrides={"densify": {"growth": 0.5}})


def test_an_mcmc_run_resumes_exactly_and_holds_its_budget(tiny_capture, tmp_path):  # noqa: F811 - the fixture
    from mogaface.core.train.trainer import Trainer

    capture = tiny_capture
    config = tiny_config(densify={"strategy": "mcmc", "growth": 1.02, "max_gaussians": 12900},
                         loss={"opacity_weight": 0.01, "size_weight": 0.01})
    straight, split = tmp_path / "straight", tmp_path / "split"
    Trainer(capture, straight, config).run()
    Trainer(capture, split, config).run(until=7)
    Trainer(capture, split, resume=True).run()
    a, a_moments, _ = final_tensors(straight)
    b, b_moments, _ = final_tensors(split)
    for name in a:
        assert torch.equal(a[name], b[name]), name
    passes = [e for e in read_events(straight) if e["event"] == "densify"]
    counts = [e["gaussians"] for e in passes]
    assert len(passes) == 3 and counts[0] == math.floor(1.02 * 12620) and counts[-1] == 12900
    last = [e for e in read_events(straight) if e["event"] == "iter"][-1]
    assert last["opacity"] > 0 and last["size"] > 0


@pytest.mark.parametrize("strategy", ["adaptive", "mcmc"])
def test_positions_that_do_not_learn_neither_wander(tiny_capture, tmp_path, strategy):  # noqa: F811 - the fixture
    """``lr.position = 0`` trains (the noise's share of a zero rate is zero, not a division by it)."""
    from mogaface.core.train.trainer import Trainer

    config = tiny_config(train={"steps": 4, "checkpoint_every": 4}, lr={"position": 0.0},
                         densify={"strategy": strategy, "start": 1, "stop": 2, "interval": 2, "max_gaussians": 12700})
    assert Trainer(tiny_capture, tmp_path / "run", config).run()["complete"]
    if strategy == "mcmc":  # the copies sit on their sources and nothing moved them
        position = final_tensors(tmp_path / "run")[0]["local_position"]
        assert len(position) == 12700 and len(torch.unique(position, dim=0)) < 12700
