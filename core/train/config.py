"""Training settings: one TOML file, every key documented, with presets for quick runs.

Precedence, lowest first: the defaults below, a ``--preset``, a ``--config`` file, command-line
flags. A run folder keeps the resolved settings as ``config.toml`` (every key written out), so a
run can be repeated or resumed from its folder alone.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import tomllib

from ..errors import InputError
from .presets import PRESETS


def _setting(default, doc: str):
    return dataclasses.field(default=default, metadata={"doc": doc})


#: What the schedules follow (``train.schedule``), the default first.
SCHEDULES = ("steps", "minutes")
#: The densification strategies (``densify.strategy``), the default first.
DENSIFY_STRATEGIES = ("adaptive", "mcmc")


@dataclasses.dataclass
class TrainSection:
    steps: int = _setting(4000, "optimisation steps in all")
    batch: int = _setting(1, "training images per step over all ranks (their mean loss); with torchrun each "
                             "rank renders its share, so one process with batch B steps as B ranks of one")
    seed: int = _setting(0, "seed of every random choice (frame order, splits)")
    threads: int = _setting(2, "CPU threads for torch and numba")
    log_every: int = _setting(10, "steps between 'iter' progress events")
    checkpoint_every: int = _setting(500, "steps between checkpoints (0: only at the end and on a signal)")
    keep_checkpoints: int = _setting(3, "how many of the newest checkpoints to keep")
    max_minutes: float = _setting(0.0, "finish early (avatar, metrics) after this much training time; 0: no limit")
    schedule: str = _setting("steps", "what the schedules (rates, densification, SH degree, cameras, bank, "
                                      "resolution) follow: 'steps' (train.steps) or 'minutes' (the schedule of "
                                      "train.steps run through train.max_minutes of training time, as many steps "
                                      "as the machine makes in it; the time ends the run)")
    resolution_start: float = _setting(1.0, "progressive resolution: the first steps train on images at this scale "
                                            "of their size, doubling in even stages to full size at "
                                            "resolution_full (1: full size throughout)")
    resolution_full: float = _setting(0.5, "fraction of the schedule (of train.steps; under schedule = 'minutes', "
                                           "of train.max_minutes) from which the images are at full size")


@dataclasses.dataclass
class LossSection:
    ssim_weight: float = _setting(0.2, "λ in (1 − λ)·L1 + λ·(1 − SSIM)")
    position_weight: float = _setting(0.01, "weight of relu(|μ_local| − position_threshold) on visible Gaussians")
    position_threshold: float = _setting(1.0, "distance from the triangle centre (in triangle units) that is free")
    scaling_weight: float = _setting(1.0, "weight of relu(exp(s_local) − scaling_threshold) on visible Gaussians")
    scaling_threshold: float = _setting(0.6, "local scale (in triangle units) that is free")
    opacity_weight: float = _setting(0.0, "weight of the mean opacity of every Gaussian (0: off; with "
                                          "densify.strategy = 'mcmc', unneeded Gaussians fade and are moved)")
    size_weight: float = _setting(0.0, "weight of the mean local scale (triangle units) of every Gaussian (0: off; "
                                       "small splats, fewer of them over each pixel)")


@dataclasses.dataclass
class LrSection:
    position: float = _setting(5e-3, "local position learning rate at step 0, times the scene extent")
    position_final_ratio: float = _setting(0.01, "position learning rate at the last step, as a fraction of the first")
    scaling: float = _setting(1.7e-2, "log-scale learning rate")
    opacity: float = _setting(0.05, "opacity logit learning rate")
    rotation: float = _setting(1e-3, "rotation quaternion learning rate")
    color: float = _setting(2.5e-3, "learning rate of the degree-0 SH (base colour)")
    color_rest_ratio: float = _setting(0.05, "learning rate of the higher SH bands, as a fraction of 'color'")
    scene_extent: float = _setting(0.0, "scene extent in metres for the position rate; 0: from the cameras "
                                        "(1.1 × the largest camera distance from their centre, as 3DGS)")


@dataclasses.dataclass
class DensifySection:
    start: int = _setting(300, "first step that densifies")
    stop: int = _setting(2000, "no densification (nor opacity reset) after this step")
    interval: int = _setting(150, "steps between densify-and-prune passes")
    grad_threshold: float = _setting(2e-4, "mean screen-space gradient (NDC units, as 3DGS) that selects a Gaussian")
    percent_dense: float = _setting(0.01, "world size (fraction of the extent) separating clone (smaller) from split")
    split_count: int = _setting(2, "Gaussians a split Gaussian becomes")
    min_opacity: float = _setting(0.005, "prune Gaussians fainter than this")
    max_screen_size: float = _setting(20.0, "after the first opacity reset, prune Gaussians wider than this (pixels)")
    max_world_size: float = _setting(0.1, "prune Gaussians larger than this fraction of the extent")
    opacity_reset_interval: int = _setting(1200, "steps between opacity resets (0: never)")
    reset_opacity: float = _setting(0.01, "opacities are clamped to at most this on a reset")
    max_gaussians: int = _setting(60000, "no densification beyond this many Gaussians")
    sh_degree_interval: int = _setting(400, "steps between raising the active SH degree by one")
    max_sh_degree: int = _setting(3, "highest SH degree")
    strategy: str = _setting("adaptive", "'adaptive': clone and split where the screen gradient is large, prune "
                                         "the faint (3DGS); 'mcmc': a fixed budget of max_gaussians, dead ones "
                                         "moved onto live ones and growth toward the budget every interval, no "
                                         "opacity resets (3DGS as MCMC)")
    growth: float = _setting(0.0, "'mcmc': each pass grows the Gaussians by this factor, up to max_gaussians; "
                                  "0: the factor that reaches max_gaussians at the last pass (densify.stop)")
    noise: float = _setting(0.1, "'mcmc': a nearly transparent Gaussian moves by this share of its own spread "
                                 "a step (times the position rate's decay), so it explores before it is moved")


@dataclasses.dataclass
class FlameSection:
    finetune: bool = _setting(False, "optimise the per-timestep FLAME parameters with the Gaussians")
    expression_lr: float = _setting(1e-3, "learning rate of the expression coefficients")
    joints_lr: float = _setting(1e-5, "learning rate of the joint rotations (global, neck, jaw, eyes)")
    translation_lr: float = _setting(1e-6, "learning rate of the translation")


#: The camera offsets' gauges (:mod:`.camera_refine`), the default first.
CAMERA_GAUGES = ("rigid", "mean", "none")
LANDMARKS_START = "landmarks"  # [cameras] start: solve the cameras from the capture's landmarks first


@dataclasses.dataclass
class CamerasSection:
    refine: bool = _setting(False, "learn a 6-DoF offset per training camera (shared by all timesteps) for captures "
                                   "whose calibration is off; writes RUN/cameras_refined.json")
    rotation_lr: float = _setting(2e-3, "learning rate of the camera rotation offsets (radians)")
    translation_lr: float = _setting(0.0, "learning rate of the camera centre offsets (metres); 0: the centres "
                                          "move only with the rig's rigid motion that the gauge takes out (the "
                                          "images pin a sideways centre shift too weakly: "
                                          "docs/notebook/2026-11-26-camera-refinement.md)")
    begin: float = _setting(0.3, "fraction of the last round's steps after which its camera offsets move (they "
                                 "hold still while its avatar forms; earlier rounds move them from the first step; "
                                 "chosen on validation frames: docs/notebook/2026-11-27-validation-and-unseen-"
                                 "subjects.md)")
    final_ratio: float = _setting(1.0, "the camera rates at the last step, as a fraction of the first (exponential "
                                       "decay; 1: constant)")
    gauge: str = _setting("rigid", "'rigid': the offsets hold no rigid motion of the whole rig (the rig as a whole "
                                   "keeps its calibrated pose); 'mean': their mean rotation and mean centre shift stay "
                                   "zero; 'none': free (a rig whose centres are measured: they hold it)")
    rounds: int = _setting(1, "train this many times, each round a fresh avatar from the cameras the last one "
                              "refined (RUN/camera_rounds/<k>; train.steps each, train.max_minutes shared)")
    start: str = _setting("", "a cameras file in the layout of RUN/cameras_refined.json the offsets start from "
                              "(an earlier run's refined cameras: a new round with a fresh avatar); '': calibrated")
    embedding: str = _setting("", "for start = 'landmarks' (ignored otherwise): where the landmarks lie on the "
                                  "head model (VHAP's landmark_embedding_with_eyes.npy, FLAME's "
                                  "flame_static_embedding.pkl or an .npz); '': the procedural head's own, or such a "
                                  "file beside the head model")
    delays: bool = _setting(False, "learn each training camera's time offset against the tracking (unsynchronised "
                                   "cameras): its mesh moves along the tracked motion; writes RUN/camera_delays.json")
    delay_lr: float = _setting(0.01, "learning rate of the camera delays (timesteps)")
    delay_begin: float = _setting(0.2, "fraction of the last round's steps after which the delays move (earlier "
                                       "rounds move them from the first step); sooner than the offsets, so the "
                                       "per-timestep FLAME fine-tuning and the Gaussians form on views at their "
                                       "own moments")
    colour: bool = _setting(False, "learn each training camera's affine colour (3×3 matrix and offset of the rendered "
                                   "foreground, identity at the start; their mean held at the identity) for a rig "
                                   "whose cameras disagree in colour; writes RUN/camera_colours.json")
    colour_lr: float = _setting(1e-3, "learning rate of the camera colours (matrix entries and offsets)")
    colour_begin: float = _setting(0.1, "fraction of the steps after which the camera colours move (before, they "
                                        "hold still while the avatar's colours form)")
    colour_weight: float = _setting(1.0, "weight of the penalty ‖M − I‖² + ‖b‖² on the camera colour of each view "
                                         "(weaker, the colours take up the avatar's own errors: docs/training.md)")
    settle_at: int = _setting(0, "step at which a cameras-only phase starts: the avatar and the FLAME parameters "
                                 "hold still while the cameras align to it (0: no such phase)")
    settle_steps: int = _setting(0, "steps of the cameras-only phase")


@dataclasses.dataclass
class EvalSection:
    at_end: bool = _setting(True, "evaluate on the val split (held-out camera) after training")
    max_frames: int = _setting(0, "val frames to evaluate, evenly spaced (0: all)")
    lpips: bool = _setting(True, "include LPIPS (needs the AlexNet weights)")
    every: int = _setting(0, "steps between quick val checks during training ('val' events; 0: none)")
    every_frames: int = _setting(6, "val frames each quick check renders (evenly spaced, no LPIPS)")


@dataclasses.dataclass
class MogafaceSection:
    mode: str = _setting("off", "expression correction: 'off' (Freeze, the baseline), 'single' (one other view of "
                                "the timestamp), 'multi' (other training views, fused by cross-attention)")
    encoder_views: int = _setting(8, "views the encoder reads per step in 'multi' mode (never the scored one)")
    bank: bool = _setting(False, "momentum-updated expression bank: its per-timestamp mean poses the mesh")
    momentum_start: float = _setting(0.5, "bank momentum at step 0 (decays linearly to momentum_end)")
    momentum_end: float = _setting(0.0, "bank momentum at the last step")
    consistency_weight: float = _setting(0.1, "weight of the per-view consistency loss against the bank's mean")
    centring_weight: float = _setting(0.0, "weight of a zero-mean prior on the correction over timestamps "
                                           "(pushes against its running mean; 0: off, as in the paper)")
    centring_decay: float = _setting(0.9, "decay per step of that running mean (its lag: about 1 / (1 - decay) "
                                          "steps)")
    rendered_weight: float = _setting(0.0, "weight of the self-supervised correction loss: the avatar rendered at "
                                          "the tracked expression plus a known offset, regressed back (0: off, "
                                          "as in the paper)")
    rendered_offset: float = _setting(0.5, "std of the known expression offsets of those renders")
    rendered_views: int = _setting(4, "views rendered per step for that loss (the encoder's cameras)")
    texture: bool = _setting(False, "latent texture attention (triplane + FLAME code → Δμ Δs Δr Δα)")
    plane_size: int = _setting(64, "triplane resolution n_f")
    plane_dim: int = _setting(16, "feature channels of each triplane plane")
    texture_hidden: int = _setting(32, "width of the texture attention and its MLP heads")
    input_size: int = _setting(128, "encoder input: views downsampled to this many pixels square")
    feature_dim: int = _setting(64, "image feature size d")
    encoder_width: int = _setting(16, "channels of the encoder's first convolution (doubled twice deeper)")
    heads: int = _setting(4, "attention heads of the multi-view fusion (divides feature_dim)")
    hidden: int = _setting(128, "hidden units of the correction MLP")
    lr: float = _setting(1e-3, "Adam learning rate of the encoder, fusion and correction head")
    texture_lr: float = _setting(1e-3, "Adam learning rate of the triplane and the texture attention")


@dataclasses.dataclass
class TrainConfig:
    train: TrainSection = dataclasses.field(default_factory=TrainSection)
    loss: LossSection = dataclasses.field(default_factory=LossSection)
    lr: LrSection = dataclasses.field(default_factory=LrSection)
    densify: DensifySection = dataclasses.field(default_factory=DensifySection)
    flame: FlameSection = dataclasses.field(default_factory=FlameSection)
    cameras: CamerasSection = dataclasses.field(default_factory=CamerasSection)
    eval: EvalSection = dataclasses.field(default_factory=EvalSection)
    mogaface: MogafaceSection = dataclasses.field(default_factory=MogafaceSection)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def check(self, source=None) -> "TrainConfig":
        """Refuse settings that cannot work, naming the key."""
        positive = {"train.steps": self.train.steps, "train.threads": self.train.threads,
                    "train.log_every": self.train.log_every, "train.keep_checkpoints": self.train.keep_checkpoints,
                    "densify.interval": self.densify.interval, "densify.split_count": self.densify.split_count - 1,
                    "densify.sh_degree_interval": self.densify.sh_degree_interval,
                    "densify.max_gaussians": self.densify.max_gaussians}
        for key, value in positive.items():
            if value <= 0:
                raise InputError(source, key, f"must be positive (got {_get(self, key)})")
        for key in ("train.checkpoint_every", "densify.start", "densify.stop", "densify.opacity_reset_interval",
                    "train.max_minutes", "eval.max_frames", "eval.every", "eval.every_frames", "lr.scene_extent", "train.seed"):
            if _get(self, key) < 0:
                raise InputError(source, key, f"must be >= 0 (got {_get(self, key)})")
        if self.train.schedule not in SCHEDULES:
            raise InputError(source, "train.schedule", f"must be one of {', '.join(SCHEDULES)} "
                                                       f"(got {self.train.schedule!r})")
        if self.train.schedule == "minutes" and self.train.max_minutes <= 0:
            raise InputError(source, "train.schedule", "'minutes' needs train.max_minutes > 0 (the time to run "
                                                       "the schedule through)")
        if self.densify.strategy not in DENSIFY_STRATEGIES:
            raise InputError(source, "densify.strategy", f"must be one of {', '.join(DENSIFY_STRATEGIES)} "
                                                         f"(got {self.densify.strategy!r})")
        if 0 < self.densify.growth < 1:
            raise InputError(source, "densify.growth", f"must be 0 (reach the budget at the last pass) or at least 1 "
                                                       f"(got {self.densify.growth})")
        if not 0 <= self.densify.max_sh_degree <= 3:
            raise InputError(source, "densify.max_sh_degree", f"must lie in [0, 3] (got {self.densify.max_sh_degree})")
        if not 0 < self.lr.position_final_ratio <= 1:
            raise InputError(source, "lr.position_final_ratio", "must lie in (0, 1]")
        if not 0 < self.cameras.final_ratio <= 1:
            raise InputError(source, "cameras.final_ratio", "must lie in (0, 1]")
        if not 0 <= self.loss.ssim_weight <= 1:
            raise InputError(source, "loss.ssim_weight", "must lie in [0, 1]")
        _check_mogaface(self.mogaface, source)
        for key in ("cameras.settle_at", "cameras.settle_steps"):
            if _get(self, key) < 0:
                raise InputError(source, key, f"must be >= 0 (got {_get(self, key)})")
        if self.cameras.rounds > 1 and not self.cameras.refine:
            raise InputError(source, "cameras.rounds", "rounds of camera refinement need cameras.refine = true")
        if self.cameras.start and not self.cameras.refine:
            raise InputError(source, "cameras.start", "starting cameras need cameras.refine = true")
        if self.cameras.settle_steps and not (self.cameras.refine and self.cameras.settle_at):
            raise InputError(source, "cameras.settle_steps", "a cameras-only phase needs cameras.refine = true and "
                                                             "cameras.settle_at > 0 (a first avatar to align to)")
        first_move = self.cameras.begin * self.train.steps
        if self.cameras.settle_steps and self.cameras.settle_at < first_move:
            raise InputError(source, "cameras.settle_at", "a cameras-only phase needs moving cameras: start it "
                                                          f"at or after step {first_move:g} (cameras.begin × "
                                                          "train.steps)")
        if self.cameras.gauge not in CAMERA_GAUGES:
            raise InputError(source, "cameras.gauge", f"expected one of {', '.join(map(repr, CAMERA_GAUGES))}, "
                                                      f"got {self.cameras.gauge!r}")
        from .config_ranges import check_ranges

        check_ranges(self, source)
        return self


def _check_mogaface(m: MogafaceSection, source) -> None:
    if m.mode not in ("off", "single", "multi"):
        raise InputError(source, "mogaface.mode", f"expected 'off', 'single' or 'multi', got {m.mode!r}")
    if m.mode == "off" and (m.bank or m.texture):
        raise InputError(source, "mogaface.mode", "the bank and the texture attention need mode 'single' or 'multi'")
    for key in ("encoder_views", "plane_size", "plane_dim", "texture_hidden", "input_size", "feature_dim",
                "encoder_width", "heads", "hidden", "rendered_views"):
        if getattr(m, key) <= 0:
            raise InputError(source, f"mogaface.{key}", f"must be positive (got {getattr(m, key)})")
    for key in ("momentum_start", "momentum_end", "centring_decay"):
        if not 0 <= getattr(m, key) < 1:
            raise InputError(source, f"mogaface.{key}", f"must lie in [0, 1) (got {getattr(m, key)})")
    if m.feature_dim % m.heads:
        raise InputError(source, "mogaface.heads", f"must divide feature_dim ({m.feature_dim})")
    for key in ("consistency_weight", "centring_weight", "rendered_weight", "rendered_offset", "lr", "texture_lr"):
        if getattr(m, key) < 0:
            raise InputError(source, f"mogaface.{key}", f"must be >= 0 (got {getattr(m, key)})")


def _get(config, dotted: str):
    section, key = dotted.split(".")
    return getattr(getattr(config, section), key)


# Settings counted in steps, which a batch of B images a step reaches B times sooner in images seen.
STEP_COUNTS = ("train.steps", "train.checkpoint_every", "densify.start", "densify.stop", "densify.interval",
               "densify.opacity_reset_interval", "densify.sh_degree_interval", "cameras.settle_at",
               "cameras.settle_steps", "eval.every")
# Learning rates a batch rule scales: the Gaussians', the per-timestep FLAME parameters', the
# cameras', the MoGaFace modules'.
RATES = ("lr.position", "lr.scaling", "lr.opacity", "lr.rotation", "lr.color", "flame.expression_lr",
         "flame.joints_lr", "flame.translation_lr", "cameras.rotation_lr", "cameras.translation_lr",
         "cameras.delay_lr", "cameras.colour_lr", "mogaface.lr", "mogaface.texture_lr")
BATCH_RULES = ("sqrt", "none")  # the rates times √B (the square-root rule for Adam, as gsplat's batches), or as given
# The rule of a run started through a launcher (one image per rank): the one that kept the quality
# per image seen in ``bench batch`` (docs/training.md).
LAUNCHED_BATCH_RULE = "sqrt"


def for_batch(config: TrainConfig, batch: int, rule: str = "sqrt") -> TrainConfig:
    """``config``, written for one image a step, for ``batch`` images a step and the same images
    seen: every step count (:data:`STEP_COUNTS`) divided by ``batch`` (at least 1 where it was
    set), the rates (:data:`RATES`) times √batch under ``rule`` "sqrt", ``train.batch`` set."""
    if rule not in BATCH_RULES:
        raise InputError(None, "batch rule", f"expected one of {', '.join(BATCH_RULES)}, got {rule!r}")
    out = copy.deepcopy(config)
    updates: dict[str, dict] = {"train": {"batch": batch}}
    for dotted in STEP_COUNTS:
        section, key = dotted.split(".")
        value = _get(config, dotted)
        updates.setdefault(section, {})[key] = max(1, round(value / batch)) if value else 0
    for dotted in RATES if rule == "sqrt" else ():
        section, key = dotted.split(".")
        updates.setdefault(section, {})[key] = _get(config, dotted) * math.sqrt(batch)
    _apply(out, updates, f"batch {batch} ({rule} rule)")
    return out.check()


def _type_name(kind) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}[kind]


def _apply(config: TrainConfig, updates: dict, source) -> None:
    """Set the keys of a ``{section: {key: value}}`` mapping, checking names and types."""
    if not isinstance(updates, dict):
        raise InputError(source, None, "expected a table of sections")
    for section_name, values in updates.items():
        section = getattr(config, section_name, None) if section_name in _SECTIONS else None
        if section is None:
            raise InputError(source, section_name, f"unknown section (known: {', '.join(_SECTIONS)})")
        if not isinstance(values, dict):
            raise InputError(source, section_name, "expected a table of settings")
        fields = {f.name: f for f in dataclasses.fields(section)}
        for key, value in values.items():
            where = f"{section_name}.{key}"
            if key not in fields:
                raise InputError(source, where, f"unknown setting (known in [{section_name}]: {', '.join(fields)})")
            kind = type(fields[key].default)
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if type(value) is not kind:
                raise InputError(source, where, f"expected {_type_name(kind)}, got {value!r}")
            if kind is float and not math.isfinite(value):
                raise InputError(source, where, f"expected a finite number, got {value!r}")
            setattr(section, key, value)


_SECTIONS = tuple(f.name for f in dataclasses.fields(TrainConfig))


def resolve(preset: str | None = None, path: str | os.PathLike | None = None,
            overrides: dict | None = None) -> TrainConfig:
    """Defaults, then ``preset``, then the TOML file at ``path``, then ``overrides``."""
    config = TrainConfig()
    if preset is not None:
        if preset not in PRESETS:
            raise InputError(None, "preset", f"unknown preset {preset!r} (known: {', '.join(PRESETS)})")
        _apply(config, PRESETS[preset], f"preset {preset}")
    if path is not None:
        _apply(config, read_toml(path), path)
    if overrides:
        _apply(config, overrides, "command line")
    return config.check(path)


def read_toml(path: str | os.PathLike) -> dict:
    """A settings file: a regular file of at most :data:`MAX_SETTINGS_BYTES`, parsed as TOML."""
    from ..io.files import check_regular_file
    from ..limits import MAX_SETTINGS_BYTES

    check_regular_file(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_SETTINGS_BYTES + 1)
        if len(data) > MAX_SETTINGS_BYTES:
            raise InputError(path, None, f"a settings file over the limit of {MAX_SETTINGS_BYTES} bytes")
        return tomllib.loads(data.decode("utf-8"))
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except RecursionError:
        raise InputError(path, None, "nested too deeply to be a settings file") from None
    except InputError:
        raise
    except (OSError, ValueError) as error:  # bad TOML, bad UTF-8, a number of 10 000 digits
        raise InputError(path, None, f"not a readable TOML file ({error})") from None


def load(path: str | os.PathLike) -> TrainConfig:
    """A config file on its own (defaults for keys it leaves out)."""
    config = TrainConfig()
    _apply(config, read_toml(path), path)
    return config.check(path)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        return str(value)
    escaped = str(value).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{escaped}"'


def to_toml(config: TrainConfig) -> str:
    """Every setting as TOML, each with its documentation as a comment."""
    lines = ["# MoGaFace training settings (every key; see docs/training.md)."]
    for section_field in dataclasses.fields(config):
        section = getattr(config, section_field.name)
        lines += ["", f"[{section_field.name}]"]
        for f in dataclasses.fields(section):
            lines.append(f"# {f.metadata['doc']}")
            lines.append(f"{f.name} = {_toml_value(getattr(section, f.name))}")
    return "\n".join(lines) + "\n"


def documented_defaults() -> list[tuple[str, object, str]]:
    """``(section.key, default, doc)`` for every setting (the docs' table)."""
    config = TrainConfig()
    rows = []
    for section_field in dataclasses.fields(config):
        section = getattr(config, section_field.name)
        for f in dataclasses.fields(section):
            rows.append((f"{section_field.name}.{f.name}", getattr(section, f.name), f.metadata["doc"]))
    return rows
