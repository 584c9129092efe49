"""Named training presets: partial settings over the defaults of :mod:`.config` (``--preset``).

Each is a ``{section: {key: value}}`` mapping checked like a settings file when applied
(:func:`.config.resolve`).
"""

# Per-timestep FLAME fine-tuning as the MoGaFace paper trains: its rates (expression 1e-3, joints
# 1e-5, translation 1e-6) are for 10⁶ steps; our runs see each timestamp a few dozen times, so all
# three are ten times the paper's.
FLAME_FINETUNE = {"finetune": True, "expression_lr": 1e-2, "joints_lr": 1e-4, "translation_lr": 1e-5}
# The full method's modules, with the zero-mean prior on the correction (ours): without it the
# modules drift by an offset shared by all timestamps, which no image pins
# (docs/notebook/2026-11-22-mogaface-ablation-iid.md).
FULL_METHOD = {"mode": "multi", "bank": True, "texture": True, "centring_weight": 1.0}

PRESETS: dict[str, dict] = {
    # A smoke run: a minute or two, no densification worth the name.
    "quick": {"train": {"steps": 200, "checkpoint_every": 100, "log_every": 5},
              "densify": {"start": 50, "stop": 150, "interval": 50, "opacity_reset_interval": 0,
                          "sh_degree_interval": 50},
              "eval": {"max_frames": 8, "lpips": False}},
    # A few minutes: enough to see a recognisable avatar.
    "demo": {"train": {"steps": 1000, "checkpoint_every": 250},
             "densify": {"start": 150, "stop": 800, "interval": 100, "opacity_reset_interval": 0,
                         "sh_degree_interval": 200},
             "eval": {"max_frames": 16}},
    # The defaults: sized for about 15 minutes on two CPU cores at 256².
    "full": {},
    # The full MoGaFace method (multi-view correction, expression bank, texture attention, the
    # per-timestep FLAME fine-tuning of the paper's implementation details and our zero-mean
    # prior), default length.
    "mogaface": {"mogaface": FULL_METHOD, "flame": FLAME_FINETUNE},
    # The demo preset with the full MoGaFace method.
    "mogaface-demo": {"train": {"steps": 1000, "checkpoint_every": 250},
                      "densify": {"start": 150, "stop": 800, "interval": 100, "opacity_reset_interval": 0,
                                  "sh_degree_interval": 200},
                      "eval": {"max_frames": 16},
                      "mogaface": FULL_METHOD, "flame": FLAME_FINETUNE},
    # The ablation's common settings (each variant sets its [mogaface] section and whether the FLAME
    # parameters are fine-tuned, at these rates): short runs.
    "mogaface-ablation": {"train": {"steps": 2000, "checkpoint_every": 500},
                          "densify": {"start": 150, "stop": 1200, "interval": 100, "opacity_reset_interval": 0,
                                      "sh_degree_interval": 300},
                          "eval": {"at_end": False},
                          "flame": {**FLAME_FINETUNE, "finetune": False}},
}
