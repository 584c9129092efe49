"""Ground-truth FLAME parameter sequences of a synthetic capture: smooth in time, seeded.

A subject performs the kinds of sequences multi-view face captures record: expression
sequences that exercise every expression component (plus jaw and eyes) with head motion, a
speech-like sequence, and a free performance (held out for self-reenactment); then a short
validation performance of its own script (``VAL``, also never trained on): settings are chosen on
``VAL``, and ``FREE`` is scored once with them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError

# name, share of the timesteps
SEQUENCES = (("EXP-1", 0.27), ("EXP-2", 0.27), ("SPEECH", 0.23), ("FREE", 0.23))
TEST_SEQUENCE = "FREE"
# The validation sequence: after the others, beyond their timesteps (so they stay as they were),
# VAL_SHARE of their count long and at least VAL_MIN.
VAL_SEQUENCE = "VAL"
VAL_SHARE = 0.05
VAL_MIN = 2
POSE_SIZES = {"rotation": 3, "neck_pose": 3, "jaw_pose": 3, "eyes_pose": 6, "translation": 3}


@dataclasses.dataclass
class Sequence:
    name: str
    params: dict[str, np.ndarray]  # name -> (T, n) float32, FLAME parameter names

    @property
    def length(self) -> int:
        return len(self.params["expr"])


def split_timesteps(total: int) -> list[int]:
    """How many timesteps each sequence of :data:`SEQUENCES` gets (at least 4 each)."""
    counts = [max(4, int(round(total * share))) for _, share in SEQUENCES]
    counts[-1] = max(4, total - sum(counts[:-1]))
    return counts


def validation_timesteps(total: int) -> int:
    """How many timesteps :data:`VAL_SEQUENCE` adds to ``total``."""
    return max(VAL_MIN, int(round(total * VAL_SHARE)))


def _bump(t: np.ndarray, centre: float, width: float) -> np.ndarray:
    """A smooth raised-cosine pulse: 0 outside ``centre ± width``, 1 at the centre."""
    x = np.clip((t - centre) / width, -1.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * x))


def _smooth_noise(rng, length: int, channels: int, correlation: float) -> np.ndarray:
    """Unit-variance noise low-pass filtered over ``correlation`` timesteps."""
    pad = int(3 * correlation) + 1
    raw = rng.normal(size=(length + 2 * pad, channels))
    kernel = np.exp(-0.5 * (np.arange(-pad, pad + 1) / max(correlation, 1e-3)) ** 2)
    kernel /= np.sqrt((kernel**2).sum())
    smooth = np.stack([np.convolve(raw[:, c], kernel, mode="valid") for c in range(channels)], axis=1)
    return smooth[:length]


def _head_motion(rng, t: np.ndarray, amplitude: float) -> dict[str, np.ndarray]:
    """Slow head turns and nods (global rotation, a little neck, tiny translation)."""
    phase = rng.uniform(0, 2 * np.pi, size=4)
    duration = max(t[-1], 1.0)
    yaw = amplitude * np.sin(2 * np.pi * t / duration + phase[0])
    pitch = 0.5 * amplitude * np.sin(4 * np.pi * t / duration + phase[1])
    roll = 0.2 * amplitude * np.sin(2 * np.pi * t / duration + phase[2])
    rotation = np.stack([pitch, yaw, roll], axis=1)
    neck = 0.3 * np.stack([0.5 * pitch, yaw, np.zeros_like(t)], axis=1)
    translation = 0.004 * np.stack([np.sin(2 * np.pi * t / duration + phase[3]), np.zeros_like(t), np.zeros_like(t)], 1)
    return {"rotation": rotation, "neck_pose": neck, "translation": translation}


def _eyes(gaze_yaw: np.ndarray, gaze_pitch: np.ndarray) -> np.ndarray:
    """Both eyes looking the same way: axis-angle (pitch about x, yaw about y) per eye."""
    one = np.stack([gaze_pitch, gaze_yaw, np.zeros_like(gaze_yaw)], axis=1)
    return np.concatenate([one, one], axis=1)


def _jaw(opening: np.ndarray) -> np.ndarray:
    """Jaw opening in radians about the x axis (positive opens the mouth)."""
    return np.stack([opening, np.zeros_like(opening), np.zeros_like(opening)], axis=1)


def expression_sequence(rng, length: int, components: list[int], n_expr: int, with_jaw: bool) -> dict:
    """Each listed component rises and falls in turn (overlapping), plus jaw or eye movements."""
    t = np.arange(length, dtype=np.float64)
    expr = np.zeros((length, n_expr))
    slot = length / max(len(components), 1)
    for k, component in enumerate(components):
        amplitude = rng.uniform(1.0, 1.6) * rng.choice([1.0, 1.0, -0.6])
        expr[:, component] = amplitude * _bump(t, (k + 0.5) * slot, 1.3 * slot)
    if with_jaw:
        jaw = 0.28 * _bump(t, 0.3 * length, 0.2 * length) + 0.15 * _bump(t, 0.75 * length, 0.15 * length)
        eyes = _eyes(np.zeros(length), np.zeros(length))
    else:
        jaw = np.zeros(length)
        eyes = _eyes(0.3 * np.sin(2 * np.pi * t / max(length, 1)), 0.15 * np.sin(4 * np.pi * t / max(length, 1)))
    return {"expr": expr, "jaw_pose": _jaw(jaw), "eyes_pose": eyes, **_head_motion(rng, t, 0.18)}


def speech_sequence(rng, length: int, lip_components: list[int], n_expr: int) -> dict:
    """Syllable-rate jaw opening with lip shapes that follow it, and small nods."""
    t = np.arange(length, dtype=np.float64)
    jaw = np.zeros(length)
    centre = rng.uniform(0.5, 2.0)
    while centre < length:
        jaw += rng.uniform(0.08, 0.2) * _bump(t, centre, rng.uniform(1.5, 2.5))
        centre += rng.uniform(2.5, 4.5)
    expr = np.zeros((length, n_expr))
    lips = _smooth_noise(rng, length, len(lip_components), correlation=3.0)
    for k, component in enumerate(lip_components):
        expr[:, component] = 0.7 * lips[:, k] * (0.4 + jaw / max(jaw.max(), 1e-6))
    eyes = _eyes(0.1 * _smooth_noise(rng, length, 1, 6.0)[:, 0], 0.05 * _smooth_noise(rng, length, 1, 6.0)[:, 0])
    return {"expr": expr, "jaw_pose": _jaw(np.clip(jaw, 0.0, 0.3)), "eyes_pose": eyes, **_head_motion(rng, t, 0.1)}


def free_sequence(rng, length: int, n_expr: int) -> dict:
    """A free performance: every component, the jaw and the eyes wander smoothly together."""
    t = np.arange(length, dtype=np.float64)
    expr = 0.7 * _smooth_noise(rng, length, n_expr, correlation=3.0)
    jaw = np.clip(0.12 + 0.1 * _smooth_noise(rng, length, 1, 3.0)[:, 0], 0.0, 0.3)
    gaze = _smooth_noise(rng, length, 2, 5.0)
    return {"expr": expr, "jaw_pose": _jaw(jaw), "eyes_pose": _eyes(0.2 * gaze[:, 0], 0.1 * gaze[:, 1]), **_head_motion(rng, t, 0.22)}


def validation_sequence(rng, length: int, n_expr: int) -> dict:
    """A script of its own, unlike FREE's wandering: short expressions of two or three random
    components each, one after another with a little overlap, the jaw opening under some of them
    and the gaze jumping between them, over slow head motion."""
    t = np.arange(length, dtype=np.float64)
    expr = np.zeros((length, n_expr))
    jaw = np.zeros(length)
    centres = np.linspace(0.0, length - 1.0, max(2, length // 3))
    width = max(1.5, 1.2 * (centres[1] - centres[0]))
    for centre in centres:
        pulse = _bump(t, centre, width)
        components = rng.choice(n_expr, size=min(n_expr, int(rng.integers(2, 4))), replace=False)
        expr[:, components] += rng.uniform(0.6, 1.5, size=len(components)) * rng.choice([1.0, -1.0], len(components)) * pulse[:, None]
        jaw += rng.uniform(0.0, 0.2) * pulse
    gaze = rng.uniform(-1.0, 1.0, size=(len(centres), 2))[np.argmin(np.abs(t[:, None] - centres[None]), axis=1)]
    return {"expr": expr, "jaw_pose": _jaw(np.clip(jaw, 0.0, 0.3)), "eyes_pose": _eyes(0.2 * gaze[:, 0], 0.1 * gaze[:, 1]),
            **_head_motion(rng, t, 0.15)}


def make_sequences(total_timesteps: int, n_shape: int, n_expr: int, mouth: list[int], seed: int) -> list[Sequence]:
    """The ground-truth parameters of every sequence of one subject: :data:`SEQUENCES` over
    ``total_timesteps``, then :data:`VAL_SEQUENCE` (:func:`validation_timesteps` more).

    ``mouth``: the expression components the speech moves
    (:func:`~mogaface.core.flame.expression_roles.mouth_components`).
    """
    rng = np.random.default_rng(seed)
    counts = split_timesteps(total_timesteps)
    half = (n_expr + 1) // 2
    raw = [
        expression_sequence(rng, counts[0], list(range(half)), n_expr, with_jaw=False),
        expression_sequence(rng, counts[1], list(range(half, n_expr)), n_expr, with_jaw=True),
        speech_sequence(rng, counts[2], list(mouth), n_expr),
        free_sequence(rng, counts[3], n_expr),
        validation_sequence(rng, validation_timesteps(total_timesteps), n_expr),  # last: the others' draws stay
    ]
    sequences = []
    for (name, _), params in zip([*SEQUENCES, (VAL_SEQUENCE, VAL_SHARE)], raw):
        length = len(params["expr"])
        full = {"shape": np.zeros((length, n_shape)), **params}
        sequences.append(Sequence(name, {k: np.asarray(v, dtype=np.float32) for k, v in full.items()}))
    return sequences


@dataclasses.dataclass(frozen=True)
class GroupNoise:
    """A tracker's error on one parameter group: ``std`` of the fluctuating part, its correlation
    length in timesteps (autocorrelation ``exp(-lag / correlation)``; 0 = independent per timestep)
    and ``bias``, the std of a constant error per coefficient (per joint axis) over the whole capture.
    """

    std: float
    correlation: float = 0.0
    bias: float = 0.0

    def check(self, name: str) -> None:
        for field in ("std", "correlation", "bias"):
            value = getattr(self, field)
            if not value >= 0:
                raise InputError(None, f"{name}_{field}".replace("_std", "_noise"), f"must be >= 0, got {value}")


# Which FLAME parameters each noise group perturbs.
NOISE_GROUPS = {"expr": ("expr",), "pose": ("rotation", "neck_pose", "jaw_pose", "eyes_pose"),
                "translation": ("translation",)}


@dataclasses.dataclass(frozen=True)
class TrackingNoise:
    """How far the "tracked" parameters stray from the truth, as a tracker's do: per group
    (expression coefficients; global, neck, jaw and eye rotations in radians; translation in
    metres) an error that drifts slowly in time plus a constant bias. See docs/data-format.md.
    """

    expr: GroupNoise = GroupNoise(0.5)
    pose: GroupNoise = GroupNoise(0.01)
    translation: GroupNoise = GroupNoise(0.001)

    def check(self) -> None:
        for name in NOISE_GROUPS:
            getattr(self, name).check(name)


def correlated_noise(rng, length: int, channels: int, correlation: float) -> np.ndarray:
    """Unit-variance stationary AR(1) noise ``(length, channels)`` with autocorrelation
    ``exp(-lag / correlation)``; independent per timestep when ``correlation`` is 0."""
    white = rng.normal(size=(length, channels))
    if correlation <= 0:
        return white
    a = float(np.exp(-1.0 / correlation))
    scale = np.sqrt(1.0 - a * a)
    out = np.empty_like(white)
    out[0] = white[0]
    for t in range(1, length):
        out[t] = a * out[t - 1] + scale * white[t]
    return out


def tracking_biases(params: dict[str, np.ndarray], noise: TrackingNoise, rng) -> dict[str, np.ndarray]:
    """The tracker's constant error per coefficient of every perturbed parameter (one per capture)."""
    biases = {}
    for group, names in NOISE_GROUPS.items():
        for name in names:
            biases[name] = rng.normal(scale=getattr(noise, group).bias, size=params[name].shape[1])
    return biases


def add_tracking_noise(params: dict[str, np.ndarray], noise: TrackingNoise, rng,
                       biases: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Ground truth of one sequence → "tracked" parameters: the group's bias (drawn here unless
    ``biases`` gives the capture's) plus correlated noise, per coefficient."""
    biases = tracking_biases(params, noise, rng) if biases is None else biases
    tracked = {k: v.copy() for k, v in params.items()}
    for group, names in NOISE_GROUPS.items():
        spec = getattr(noise, group)
        for name in names:
            length, channels = tracked[name].shape
            drift = spec.std * correlated_noise(rng, length, channels, spec.correlation)
            tracked[name] = tracked[name] + biases[name][None] + drift
    return {k: v.astype(np.float32) for k, v in tracked.items()}
