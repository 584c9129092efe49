"""Per-scene settings of the MoGaFace panel (``scene.mogaface``)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ..operators.train import PRESET_ITEMS


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
    minutes: FloatProperty(name="Minutes", default=0.0, min=0.0, soft_max=24 * 60.0,
                           description="Train for this many minutes, the preset's whole schedule run through them "
                                       "at this machine's pace (0: train the steps)")
    preset: EnumProperty(name="Preset", default="demo", description="Training settings preset (docs/training.md)",
                         items=PRESET_ITEMS)
    seed: IntProperty(name="Seed", default=0, min=0, description="Random seed of training")
    camera_rounds: IntProperty(
        name="Camera Rounds", default=0, min=0, max=16,
        description="For captures whose calibration is off: 0 trusts the cameras; 1 polishes a nearly right "
                    "calibration; N refines them in N rounds, each a fresh avatar (N times the training time; 3 "
                    "recommended when the cameras are off by more than a pixel)")
    cameras_from_landmarks: BoolProperty(
        name="Start from Landmarks", default=False,
        description="Refined cameras start from cameras solved from the capture's 2D landmarks (landmark2d/, as VHAP "
                    "writes them) instead of its calibration")
    camera_centres_measured: BoolProperty(
        name="Centres Measured", default=False,
        description="The rig's camera positions are measured (to a couple of millimetres): refinement turns each "
                    "camera about its centre and lets the centres hold the rig, instead of keeping the rig's "
                    "overall pose as calibrated")
    camera_delays: BoolProperty(
        name="Unsynchronised Cameras", default=False,
        description="Learn each camera's time offset against the tracking, for a rig whose cameras are not "
                    "triggered together (writes camera_delays.json in the run folder)")
    viewport_resolution: IntProperty(
        name="Viewport Resolution", default=100, min=10, max=100, subtype="PERCENTAGE",
        description="Size of the avatar drawn in a still 3D view, in percent of the view's own pixels "
                    "(100: sharp, one render pixel per screen pixel)")
    viewport_navigate_resolution: IntProperty(
        name="While Navigating", default=160, min=32, max=4096,
        description="Longest side in pixels of the avatar while the view moves (faster)")
    footage_clip: StringProperty(
        name="Movie Clip", description="A Movie Clip of this file to track or drive from (empty: pick a file)")
    drive_tolerance: FloatProperty(
        name="Tolerance", default=0.001, min=0.0, soft_max=0.1, precision=4,
        description="Drive from Footage drops keys that linear interpolation gives within this (radians, metres, "
                    "expression units; 0: a key every frame)")
    drive_keep_head_still: BoolProperty(
        name="Keep Head Still", default=False,
        description="Drive from Footage keys only the face (expression, jaw, eyes): the head keeps its pose")
