"""Unsynchronised cameras: the generator renders each camera at its own moment, a known delay is
recovered from the images through the tracked motion, and the delays survive checkpoints and
reach the run folder."""

import json

import numpy as np
import pytest
import torch
from test_evaluate_fixtures import tiny_capture_like

from mogaface.core.avatar.avatar import Avatar
from mogaface.core.correction.avatar import render_world
from mogaface.core.data.capture import Capture
from mogaface.core.data.generator import params_at
from mogaface.core.errors import InputError
from mogaface.core.flame.model import FlameModel
from mogaface.core.run.names import DELAYS_FILE
from mogaface.core.train import config as C
from mogaface.core.train.camera_delays import CameraDelays, _neighbours, read_delays
from mogaface.core.train.checkpoint import latest_checkpoint, load_checkpoint
from mogaface.core.train.data import TrainingData
from mogaface.core.train.presets import FULL_METHOD
from mogaface.core.train.trainer import Trainer


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return tiny_capture_like(tmp_path_factory, "delayed_capture", camera_delay=0.4)


def test_neighbours_stay_inside_a_sequence():
    found = _neighbours([0, 1, 2, 5, 6, 9], {"A": [0, 1, 2], "B": [5, 6, 7], "C": [9]})
    assert found == {0: (0, 1), 1: (0, 2), 2: (1, 2), 5: (5, 6), 6: (5, 6)}  # 9 has no neighbour
    assert _neighbours([3, 4], {})[3] == (3, 4)  # no sequences: one


def test_the_move_follows_a_bending_motion_exactly_to_second_order():
    """Inside a sequence the move is exact for a motion that is a parabola in time (the velocity
    alone would miss ``δ²/2·a``); at a sequence's end it is the line to the one neighbour."""
    generator = torch.Generator().manual_seed(3)
    a, b, c = (torch.randn(5, 3, generator=generator, dtype=torch.float64) for _ in range(3))

    def posed(t):
        return c + b * t + a * t * t

    delays = CameraDelays(["cam"], range(5), {"S": list(range(5))})
    for delay in (0.35, -0.6):
        delays.start_from({"cam": delay})
        moved = delays.shift("cam", 2, posed).to(torch.float64)
        assert torch.allclose(moved, posed(2 + delay) - posed(2), atol=1e-6)
        assert not torch.allclose(delay * (posed(3) - posed(1)) / 2, posed(2 + delay) - posed(2), atol=1e-3)
        at_end = delays.shift("cam", 4, posed).to(torch.float64)
        assert torch.allclose(at_end, delay * (posed(4) - posed(3)), atol=1e-6)


def test_each_camera_is_rendered_at_its_own_moment(capture):
    info = json.loads((capture / "capture_info.json").read_text())
    delays = info["camera_delays"]
    assert delays[info["val_camera"]] == 0.0 and sum(abs(d) > 0.05 for d in delays.values()) >= 1
    # The generator's moment: the parameters between timesteps, linearly; clamped at the ends.
    params = {"expr": np.array([[0.0], [1.0], [3.0]], np.float32)}
    assert params_at(params, 1.25)["expr"][0] == pytest.approx(1.5)
    assert params_at(params, -0.5)["expr"][0] == 0.0 and params_at(params, 2.7)["expr"][0] == 3.0
    # A delayed camera's silhouette is the mesh of its moment, not of the timestep.
    from mogaface.core.data.mesh_render import render_mesh

    cap = Capture.open(capture)
    model = FlameModel.load(capture / "head.pkl")
    cid = max(delays, key=lambda c: abs(delays[c]))
    frame = next(f for f in cap.frames() if f.camera_id == cid and f.timestep_index == 5)
    sequence = next(name for name, (a, b) in info["sequences"].items() if a <= 5 < b)
    start, end = info["sequences"][sequence]
    truth = [dict(np.load(capture / "flame_param_gt" / f"{t:05d}.npz")) for t in range(start, end)]
    stacked = {k: np.stack([p[k].reshape(-1) for p in truth]) for k in truth[0] if k != "static_offset"}
    silhouettes = {}
    for name, moment in (("own", params_at(stacked, 5 - start + delays[cid])), ("timestep", params_at(stacked, 5 - start))):
        with torch.no_grad():
            vertices = model(**{k: torch.from_numpy(v)[None] for k, v in moment.items()})[0].double().numpy()
        arrays = model.arrays
        silhouettes[name] = render_mesh(vertices, arrays.faces, arrays.vt, arrays.ft,
                                        arrays.texture.astype(np.float32) / 255, cap.camera(frame), (1, 1, 1),
                                        supersample=1)[1]
    mask = cap.load_image(frame)[1]
    own, other = (float(np.abs(silhouettes[k] - mask).mean()) for k in ("own", "timestep"))
    assert own < 0.003 and other > 5 * own, (own, other)  # the mask is an 8-bit PNG


def test_a_known_delay_is_recovered_through_the_tracked_motion(capture):
    """A fixed avatar rendered at its mesh moved 0.3 timesteps along the motion is the target; the
    delay alone, from zero, learns 0.3 back."""
    data = TrainingData(capture)
    table = data.flame_table()
    avatar = Avatar.initial(capture / "head.pkl", 0)
    with torch.no_grad():
        avatar.gaussians.sh_dc.copy_(torch.rand(avatar.gaussians.sh_dc.shape,
                                                generator=torch.Generator().manual_seed(1)) - 0.5)
        avatar.gaussians.opacity_logit.fill_(3.0)
    frame = next(f for f in data.frames if 0 < f.timestep_index < 4)
    camera = data.capture.camera(frame)

    def posed(t):
        with torch.no_grad():
            return avatar.posed_vertices(table.params(t))

    delays = CameraDelays([frame.camera_id], table.timesteps, data.capture.sequences)

    def image(shift):
        world = avatar.gaussians.world(posed(frame.timestep_index) + shift, avatar.flame.faces)
        return render_world({k: v.detach() if k != "means" else v for k, v in world.items()}, camera,
                            data.background).rgb

    with torch.no_grad():
        delays.delay[0].fill_(0.3)
        target = image(delays.shift(frame.camera_id, frame.timestep_index, posed))
        delays.delay[0].fill_(0.0)
    optimiser = torch.optim.Adam(delays.parameters(), lr=0.02)
    for _ in range(60):
        optimiser.zero_grad()
        loss = (image(delays.shift(frame.camera_id, frame.timestep_index, posed)) - target).abs().mean()
        loss.backward()
        optimiser.step()
    assert delays.values()[frame.camera_id] == pytest.approx(0.3, abs=0.03)


def _config(steps, **cameras):
    return C.resolve(overrides={
        "train": {"steps": steps, "threads": 1, "log_every": 1, "checkpoint_every": 4},
        "densify": {"start": 100, "stop": 200, "interval": 50, "opacity_reset_interval": 0},
        "eval": {"at_end": False, "lpips": False},
        "cameras": {"delays": True, "delay_begin": 0.0, **cameras},
    })


def test_delays_survive_a_checkpoint_and_reach_the_run_folder(capture, tmp_path):
    straight = Trainer(capture, tmp_path / "straight", _config(8)).run()
    assert straight["complete"]
    written = read_delays(tmp_path / "straight" / DELAYS_FILE)
    assert set(written) == {f.camera_id for f in TrainingData(capture).frames}
    assert any(abs(v) > 1e-4 for v in written.values())  # they moved
    state = load_checkpoint(latest_checkpoint(tmp_path / "straight" / "checkpoints"))
    assert [round(float(v), 6) for v in state["delays"]["delay"]] == [round(written[c], 6) for c in sorted(written)]

    assert Trainer(capture, tmp_path / "split", _config(8)).run(until=4)["step"] == 4
    assert "delays" in load_checkpoint(latest_checkpoint(tmp_path / "split" / "checkpoints"))
    resumed = Trainer(capture, tmp_path / "split", resume=True).run()
    assert resumed["complete"]
    again = read_delays(tmp_path / "split" / DELAYS_FILE)
    assert again == pytest.approx(written, abs=1e-6)

    from mogaface.core.evaluate.camera_error import camera_errors

    true_delays = json.loads((capture / "capture_info.json").read_text())["camera_delays"]
    report = camera_errors(Capture.open(capture), tmp_path / "straight")["delays"]
    assert report["cameras"] == len(written)
    assert report["assumed_synchronised_mean_abs"] == pytest.approx(np.mean([abs(true_delays[c]) for c in written]))
    assert report["learned_mean_abs_error"] == pytest.approx(np.mean([abs(written[c] - true_delays[c]) for c in written]))

    # A run (a camera round) that starts from another's cameras starts from its delays as well.
    assert Trainer(capture, tmp_path / "round1", _config(4, refine=True)).run()["complete"]
    learned = read_delays(tmp_path / "round1" / DELAYS_FILE)
    start = str(tmp_path / "round1" / "cameras_refined.json")
    assert Trainer(capture, tmp_path / "round2", _config(4, refine=True, start=start)).camera_delays.values() == \
        pytest.approx(learned, abs=1e-7)
    assert not any(Trainer(capture, tmp_path / "fresh", _config(4, refine=True)).camera_delays.values().values())

    (tmp_path / "bad.json").write_text(json.dumps({"cam00": "late"}))
    with pytest.raises(InputError, match="cam00"):
        read_delays(tmp_path / "bad.json")


def test_the_delays_and_the_camera_offsets_begin_each_at_their_own_step(capture, tmp_path):
    def moved(config, name):
        trainer = Trainer(capture, tmp_path / name, config)
        assert trainer.run()["complete"]
        offsets = max(float(p.detach().abs().max()) for p in trainer.camera_offsets.rotation)
        return offsets, max(abs(v) for v in trainer.camera_delays.values().values())

    offsets, delays = moved(_config(4, refine=True, begin=0.9, delay_lr=0.2), "delays_first")
    assert offsets == 0.0 and delays > 1e-3
    offsets, delays = moved(_config(4, refine=True, begin=0.0, delay_begin=0.9, rotation_lr=1e-2), "offsets_first")
    assert offsets > 0.0 and delays == 0.0


def test_delays_train_beside_the_mogaface_modules_and_move_the_scored_views(capture, tmp_path):
    """The MoGaFace path poses its mesh itself: the delay moves it there too, and `eval` renders a
    delayed camera's views of the unseen sequence at its moment (a modulated avatar included)."""
    from mogaface.core.evaluate.evaluation import evaluate_run

    config = C.resolve(overrides={
        "train": {"steps": 4, "threads": 1, "log_every": 1, "checkpoint_every": 100},
        "densify": {"start": 100, "stop": 200, "interval": 50, "opacity_reset_interval": 0},
        "eval": {"at_end": False, "lpips": False},
        "mogaface": {**FULL_METHOD, "encoder_views": 2, "input_size": 32},
        "cameras": {"delays": True, "delay_begin": 0.0, "delay_lr": 0.2},
    })
    run = tmp_path / "run"
    assert Trainer(capture, run, config).run()["complete"]
    learned = read_delays(run / DELAYS_FILE)
    assert any(abs(v) > 1e-3 for v in learned.values())

    def scores(out):
        result = evaluate_run(run, protocols=["self_reenactment"], max_frames=6, lpips=False, out_dir=out)
        return {(r["timestep"], r["camera"]): r["psnr"] for r in result["protocols"]["self_reenactment"]["per_frame"]}

    with_delays = scores(tmp_path / "a")
    (run / DELAYS_FILE).rename(tmp_path / "kept.json")
    without = scores(tmp_path / "b")
    moved = {key for key in with_delays if abs(with_delays[key] - without[key]) > 1e-6}
    assert moved and all(camera in learned for _, camera in moved)
