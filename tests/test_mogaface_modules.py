"""MoGaFace modules on their own: shapes, zero starts, bank EMA maths, local-space offsets."""

import math

import pytest
import torch

from mogaface.core.avatar.gaussians import BoundGaussians
from mogaface.core.correction.bank import ExpressionBank, consistency_loss, momentum_at
from mogaface.core.correction.model import MoGaFace
from mogaface.core.correction.posing import world_with_offsets
from mogaface.core.correction.texture_attention import LatentTextureAttention
from mogaface.core.errors import InputError

SPEC = dict(mode="multi", bank=True, texture=True, input_size=32, feature_dim=16, encoder_width=4, heads=2,
            hidden=16, plane_size=8, plane_dim=4, texture_hidden=8, n_expr=5)


def _mesh(seed=0, faces=12):
    g = torch.Generator().manual_seed(seed)
    vertices = torch.randn(3 * faces, 3, generator=g) * 0.1
    return vertices, torch.arange(3 * faces).view(faces, 3)


def _code_params(n_expr, seed=None):
    """A frame's FLAME parameters (batch 1) as the texture attention reads them (zeros: rest)."""
    g = torch.Generator().manual_seed(seed) if seed is not None else None
    draw = (lambda n: 0.3 * torch.randn(1, n, generator=g)) if g is not None else (lambda n: torch.zeros(1, n))
    return {"expr": draw(n_expr), "jaw_pose": draw(3), "neck_pose": draw(3), "eyes_pose": draw(6),
            "rotation": draw(3), "translation": draw(3)}


def _gaussians(n_faces, seed=0):
    g = BoundGaussians.one_per_triangle(n_faces, 1)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        g.local_position.normal_(0, 0.3, generator=gen)
        g.local_log_scale.normal_(-1, 0.2, generator=gen)
        g.local_rotation.add_(0.2 * torch.randn(g.local_rotation.shape, generator=gen))
    return g


def test_shapes_and_zero_start():
    vertices, faces = _mesh()
    model = MoGaFace(SPEC, [0, 1, 2], ["a", "b", "c", "d"], vertices)
    images = torch.rand(3, 3, 32, 32)
    per_view, feature = model.correct(images, torch.randn(5))
    assert per_view.shape == (3, 5) and feature.shape == (16,)
    assert torch.count_nonzero(per_view) == 0  # zero-initialised last layer: no correction at start
    g = _gaussians(len(faces))
    offsets = model.texture_offsets(g, faces, _code_params(5))
    assert {k: tuple(v.shape) for k, v in offsets.items()} == {
        "position": (12, 3), "log_scale": (12, 3), "rotation": (12, 4), "opacity": (12, 1)}
    plain = g.world(vertices, faces)
    modulated = world_with_offsets(g, vertices, faces, offsets)
    for key in plain:
        assert torch.equal(plain[key], modulated[key]), key


def test_single_mode_regresses_each_view_alone():
    vertices, _ = _mesh()
    model = MoGaFace({**SPEC, "mode": "single"}, [0], ["a", "b"], vertices)
    torch.nn.init.normal_(model.head.out.weight)
    images = torch.rand(2, 3, 32, 32)
    both, _ = model.correct(images, torch.zeros(5))
    first, _ = model.correct(images[:1], torch.zeros(5))
    assert torch.allclose(both[:1], first, atol=1e-6)
    multi = MoGaFace(SPEC, [0], ["a", "b"], vertices)
    multi.load_state_dict(model.state_dict())
    fused_both, _ = multi.correct(images, torch.zeros(5))
    fused_first, _ = multi.correct(images[:1], torch.zeros(5))
    assert not torch.allclose(fused_both[:1], fused_first, atol=1e-6)  # the other view informs it


def test_off_mode_refuses_bank_and_texture():
    with pytest.raises(InputError, match="mogaface.mode"):
        MoGaFace({**SPEC, "mode": "off"}, [0], ["a"], _mesh()[0])


def test_momentum_schedule_is_linear():
    assert momentum_at(0, 100, 0.9, 0.1) == pytest.approx(0.9)
    assert momentum_at(50, 100, 0.9, 0.1) == pytest.approx(0.5)
    assert momentum_at(100, 100, 0.9, 0.1) == pytest.approx(0.1)
    assert momentum_at(500, 100, 0.9, 0.1) == pytest.approx(0.1)


def test_bank_ema_and_mean():
    bank = ExpressionBank(2, 3, 2)
    slots = torch.tensor([0, 2])
    first = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    bank.update(1, slots, first, momentum=0.8)  # never written: taken as is
    assert torch.equal(bank.values[1, slots], first)
    second = torch.tensor([[0.0, 0.0], [10.0, 10.0]])
    bank.update(1, slots, second, momentum=0.8)
    expected = 0.8 * first + 0.2 * second
    assert torch.allclose(bank.values[1, slots], expected)
    assert torch.allclose(bank.mean(1), expected.mean(0))  # unwritten slot 1 does not count
    assert torch.equal(bank.mean(0), torch.zeros(2)) and not bank.has(0)
    # The differentiable path: blended values substitute their slots in the mean.
    fresh = torch.tensor([[2.0, 2.0]], requires_grad=True)
    blended = bank.blend(1, torch.tensor([1]), fresh, 0.5)
    mean = bank.mean_with(1, torch.tensor([1]), blended)
    assert torch.allclose(mean, (expected.sum(0) + fresh.detach()[0]) / 3)
    mean.sum().backward()
    assert torch.allclose(fresh.grad, torch.full((1, 2), 1 / 3))
    with pytest.raises(InputError):
        bank.blend(1, slots, second, 1.0)


def test_consistency_loss():
    corrections = torch.tensor([[1.0, 0.0], [3.0, 0.0]], requires_grad=True)
    target = torch.tensor([2.0, 0.0])
    loss = consistency_loss(corrections, target)
    assert loss.item() == pytest.approx(0.5)
    loss.backward()
    assert torch.allclose(corrections.grad, torch.tensor([[-0.5, 0.0], [0.5, 0.0]]))


def test_texture_offsets_move_with_the_mesh():
    """Offsets live in triangle space: a rigid motion of the mesh moves the modulated Gaussians rigidly."""
    vertices, faces = _mesh(3)
    g = _gaussians(len(faces), 1)
    texture = LatentTextureAttention(8, 8, 4, 8)  # an 8-number code
    for head in texture.heads.values():
        torch.nn.init.normal_(head.weight, std=0.3)
    points = torch.rand(len(faces), 3) * 2 - 1
    offsets = texture(points, torch.randn(8))
    angle = 0.7
    rotation = torch.tensor([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])
    shift = torch.tensor([0.1, -0.2, 0.3])
    before = world_with_offsets(g, vertices, faces, offsets)
    after = world_with_offsets(g, vertices @ rotation.T + shift, faces, offsets)
    assert torch.allclose(after["means"], before["means"] @ rotation.T + shift, atol=1e-5)
    assert torch.allclose(after["scales"], before["scales"], atol=1e-5)
    assert torch.allclose(after["opacities"], before["opacities"])
    # and the offsets do move the Gaussians (in the triangle's frame, not the world's)
    plain = g.world(vertices, faces)
    assert not torch.allclose(plain["means"], before["means"])


def test_texture_forward_is_the_layers_read_one_by_one_to_float64():
    """The folded forward with the numba triplane read against the module read layer by layer
    through ``F.grid_sample`` in float64: offsets and every parameter's gradient, with points on
    the planes' borders and between texel centres, whatever the number of threads."""
    import numba

    texture = LatentTextureAttention(8, plane_size=6, plane_dim=4, hidden=8)
    g = torch.Generator().manual_seed(4)
    for head in texture.heads.values():
        torch.nn.init.normal_(head.weight, std=0.3, generator=g)
    points = (torch.rand(300, 3, generator=g) * 2.4 - 1.2).clamp(-1, 1)
    points[:6] = torch.tensor([-1.0, 1.0, 1 / 6])[torch.randint(0, 3, (6, 3), generator=g)]
    code = torch.randn(8, generator=g)
    upstream = {k: torch.randn(300, v.out_features, generator=g) for k, v in texture.heads.items()}

    def run(module, forward, dtype):
        module.zero_grad()
        out = forward(points.to(dtype), code.to(dtype))
        sum((out[k] * upstream[k].to(dtype)).sum() for k in out).backward()
        return out, [p.grad.clone() for p in module.parameters()]

    reference = LatentTextureAttention(8, plane_size=6, plane_dim=4, hidden=8).double()
    reference.load_state_dict(texture.state_dict())
    expected, expected_grads = run(reference, reference.forward_layers, torch.float64)
    old_threads = numba.get_num_threads()
    runs = []
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            runs.append(run(texture, texture.forward, torch.float32))
    finally:
        numba.set_num_threads(old_threads)
    (out, grads), (_, grads_again) = runs
    for k in expected:
        assert torch.allclose(out[k].double(), expected[k], atol=1e-5), k
    for (name, _), got, want, again in zip(texture.named_parameters(), grads, expected_grads, grads_again):
        assert torch.allclose(got.double(), want, rtol=1e-4, atol=1e-5 * want.abs().max().item()), name
        assert torch.equal(got, again), name  # the same bits on one thread or two
    assert expected_grads[0].abs().max() > 0 and out["position"].abs().max() > 1e-3


def test_texture_read_at_a_nan_point_stays_inside_the_planes():
    """A diverged Gaussian (NaN position) changes its own row only (NaN, or a border texel under
    fast maths): the kernels clamp the texel indices as integers, so nothing is read or written
    past the planes, and its gradient lands inside them."""
    texture = LatentTextureAttention(8, plane_size=6, plane_dim=4, hidden=8)
    points = torch.rand(50, 3) * 2 - 1
    clean = texture.sample(points)
    broken = points.clone()
    broken[7] = float("nan")
    read = texture.sample(broken)
    assert torch.equal(torch.cat([read[:7], read[8:]]), torch.cat([clean[:7], clean[8:]]))
    read.sum().backward()
    with_nan = texture.planes.grad.clone()
    texture.planes.grad = None
    torch.cat([clean[:7], clean[8:]]).sum().backward()
    # the NaN point's share lands on at most its four texels of each plane, all channels
    changed = ~torch.isclose(with_nan, texture.planes.grad, atol=1e-6, equal_nan=False)
    assert changed.any(dim=1).sum() <= 3 * 4


def test_model_file_round_trip(tmp_path):
    vertices, _ = _mesh()
    model = MoGaFace(SPEC, [0, 4], ["a", "b"], vertices)
    model.bank.update(1, torch.tensor([1]), torch.ones(1, 5), 0.5)
    model.save(tmp_path / "m.pt")
    again = MoGaFace.load(tmp_path / "m.pt")
    assert again.spec == model.spec and again.timesteps == [0, 4]
    for key, value in model.state_dict().items():
        assert torch.equal(value, again.state_dict()[key]), key


def _trained_like(model):
    """Non-zero output heads, as after training (they start at zero)."""
    with torch.no_grad():
        for head in model.texture.heads.values():
            torch.nn.init.normal_(head.weight, std=0.3, generator=torch.Generator().manual_seed(4))
    return model


def test_texture_follows_the_flame_code_and_nothing_per_timestamp():
    """The texture reads the expression and jaw/neck/eye rotations: it changes with them, not with the
    rigid head pose, and two timestamps given the same parameters look the same."""
    vertices, faces = _mesh()
    model = _trained_like(MoGaFace(SPEC, [0, 1, 2], ["a", "b"], vertices))
    g = _gaussians(len(faces))
    params = _code_params(5, seed=1)
    base = model.texture_offsets(g, faces, params)
    for name in ("expr", "jaw_pose", "neck_pose", "eyes_pose"):
        moved = {**params, name: params[name] + 0.2}
        assert (model.texture_offsets(g, faces, moved)["position"] - base["position"]).abs().max() > 1e-4, name
    rigid = {**params, "rotation": params["rotation"] + 0.5, "translation": params["translation"] + 0.1}
    assert torch.equal(model.texture_offsets(g, faces, rigid)["position"], base["position"])
    # Nothing in the model is indexed by timestamp for the texture: the same code, the same offsets,
    # whatever the bank or the other per-timestamp memory holds.
    model.bank.update(1, torch.tensor([0]), torch.ones(1, 5), 0.0)
    assert torch.equal(model.texture_offsets(g, faces, params)["position"], base["position"])
    assert not any("feature" in key for key in model.state_dict())


def test_version_1_module_files_load_without_texture_and_are_refused_with_it(tmp_path):
    from mogaface.core.io.torch_file import save_torch_state

    vertices, _ = _mesh()
    for texture in (False, True):
        model = MoGaFace({**SPEC, "texture": texture}, [0, 4], ["a", "b"], vertices)
        state = model.to_file_state()
        state["version"] = 1
        state["state"]["default_feature"] = torch.zeros(16)  # what version 1 also stored
        state["state"]["timestep_features"] = torch.zeros(2, 16)
        save_torch_state(state, tmp_path / "old.pt")
        if texture:
            with pytest.raises(InputError, match="version-1 .*texture attention.*train the run again"):
                MoGaFace.load(tmp_path / "old.pt")
        else:
            again = MoGaFace.load(tmp_path / "old.pt")
            assert torch.equal(again.bank.values, model.bank.values)
