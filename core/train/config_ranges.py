"""The allowed range of every numeric training setting (inclusive): wide enough for any sensible
run, narrow enough that no value exhausts memory, aborts the process or trains backwards."""

from __future__ import annotations

import dataclasses

from ..errors import InputError

BIG = 10 ** 9

RANGES: dict[str, tuple[float, float]] = {
    "train.steps": (1, BIG), "train.seed": (0, 2 ** 63 - 1), "train.threads": (1, 256),
    "train.log_every": (1, BIG), "train.checkpoint_every": (0, BIG), "train.keep_checkpoints": (1, 1000),
    "train.max_minutes": (0, 10 ** 7), "train.resolution_start": (1 / 64, 1), "train.resolution_full": (0, 1),
    # views per step; more would hold that many renders' autograd graphs at once
    "train.batch": (1, 256),
    "loss.ssim_weight": (0, 1), "loss.position_weight": (0, 1e6), "loss.position_threshold": (0, 1e6),
    "loss.scaling_weight": (0, 1e6), "loss.scaling_threshold": (0, 1e6), "loss.opacity_weight": (0, 1e6),
    "loss.size_weight": (0, 1e6),
    "lr.position": (0, 10), "lr.position_final_ratio": (1e-12, 1), "lr.scaling": (0, 10), "lr.opacity": (0, 10),
    "lr.rotation": (0, 10), "lr.color": (0, 10), "lr.color_rest_ratio": (0, 100), "lr.scene_extent": (0, 1e6),
    "densify.start": (0, BIG), "densify.stop": (0, BIG), "densify.interval": (1, BIG),
    "densify.grad_threshold": (1e-12, 1e6), "densify.percent_dense": (0, 1), "densify.split_count": (2, 16),
    "densify.min_opacity": (0, 1), "densify.max_screen_size": (0, 1e6), "densify.max_world_size": (0, 1e6),
    "densify.opacity_reset_interval": (0, BIG), "densify.reset_opacity": (0, 1),
    "densify.max_gaussians": (1, 50_000_000), "densify.sh_degree_interval": (1, BIG), "densify.max_sh_degree": (0, 3),
    "densify.growth": (0, 10), "densify.noise": (0, 100),
    "flame.expression_lr": (0, 10), "flame.joints_lr": (0, 10), "flame.translation_lr": (0, 10),
    "cameras.rotation_lr": (0, 1), "cameras.translation_lr": (0, 1), "cameras.begin": (0, 0.99),
    "cameras.settle_at": (0, BIG), "cameras.settle_steps": (0, BIG), "cameras.rounds": (1, 16),
    "cameras.final_ratio": (1e-12, 1), "cameras.delay_lr": (0, 1), "cameras.delay_begin": (0, 0.99),
    "cameras.colour_lr": (0, 1), "cameras.colour_weight": (0, 1e6), "cameras.colour_begin": (0, 0.99),
    "eval.max_frames": (0, BIG), "eval.every": (0, BIG), "eval.every_frames": (0, 100_000),
    "mogaface.encoder_views": (1, 256), "mogaface.momentum_start": (0, 0.999999), "mogaface.momentum_end": (0, 0.999999),
    "mogaface.consistency_weight": (0, 1e6), "mogaface.centring_weight": (0, 1e6),
    "mogaface.centring_decay": (0, 0.999999), "mogaface.rendered_weight": (0, 1e6),
    "mogaface.rendered_offset": (0, 100), "mogaface.rendered_views": (1, 256), "mogaface.plane_size": (1, 1024),
    "mogaface.plane_dim": (1, 256), "mogaface.texture_hidden": (1, 1024), "mogaface.input_size": (8, 1024),
    "mogaface.feature_dim": (1, 1024), "mogaface.encoder_width": (1, 256), "mogaface.heads": (1, 64),
    "mogaface.hidden": (1, 4096), "mogaface.lr": (0, 10), "mogaface.texture_lr": (0, 10),
}


def numeric_settings(config) -> list[tuple[str, object]]:
    """``(section.key, value)`` of every int or float setting."""
    out = []
    for section_field in dataclasses.fields(config):
        section = getattr(config, section_field.name)
        for f in dataclasses.fields(section):
            value = getattr(section, f.name)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                out.append((f"{section_field.name}.{f.name}", value))
    return out


def check_ranges(config, source) -> None:
    """Refuse any numeric setting outside its range, naming the key and the range."""
    for key, value in numeric_settings(config):
        low, high = RANGES[key]
        if not low <= value <= high:
            raise InputError(source, key, f"must lie in [{low:g}, {high:g}] (got {value!r})")
