"""Per-scene settings of the MoGaFace panel (``scene.mogaface``)."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty


class MoGaFaceSceneSettings(bpy.types.PropertyGroup):
    """Where this scene's capture, head, tracking and training run live, and how to train."""

    capture_folder: StringProperty(
        name="Capture", subtype="DIR_PATH", description="Capture folder (GaussianAvatars/VHAP layout)"
    )
    head_file: StringProperty(name="Head", subtype="FILE_PATH", description="FLAME-format head model (.pkl or .npz)")
    identity_file: StringProperty(
        name="Identity",
        subtype="FILE_PATH",
        description="Optional flame_param .npz whose shape sets the head's identity",
    )
    tracking_folder: StringProperty(
        name="Tracking", subtype="DIR_PATH", description="flame_param folder whose expressions and poses drive the head"
    )
    run_folder: StringProperty(name="Run", subtype="DIR_PATH", description="Folder for a training run's checkpoints")
    avatar_file: StringProperty(name="Avatar", subtype="FILE_PATH", description="A trained avatar file")
    iterations: IntProperty(name="Steps", default=0, min=0, description="Training steps (0: the preset's)")
    preset: EnumProperty(
        name="Preset", default="demo", description="Training settings preset (docs/training.md)",
        items=(("quick", "Quick", "200 steps"), ("demo", "Demo", "1000 steps"), ("full", "Full", "the defaults")),
    )
    seed: IntProperty(name="Seed", default=0, min=0, description="Random seed of training")
