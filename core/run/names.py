"""Every file and folder name of a run folder, in one place (imports nothing: Blender reads it too).

::

    RUN/config.toml               the resolved settings (every key)
    RUN/head.pkl                  copy of the capture's head model (beside avatar.pt)
    RUN/run.json                  capture path, splits, background, extent, final step, wall time
    RUN/events.jsonl              progress events, one JSON object a line
    RUN/refine_tracking_events.jsonl  refine-tracking's progress events
    RUN/checkpoints/step_NNNNNN.pt, RUN/checkpoints/latest
    RUN/avatar.pt                 the trained avatar (Avatar.save)
    RUN/mogaface.pt               the MoGaFace modules (runs trained with them)
    RUN/flame_param/TTTTT.npz     FLAME parameters used for each training timestep (VHAP form)
    RUN/flame_param_corrected/    the same with the correction modules' expressions (MoGaFace runs)
    RUN/metrics_train_end.json    quick val-split metrics after training
    RUN/cameras_refined.json      learned camera poses (camera refinement)
    RUN/camera_delays.json        learned camera delays (camera id → timesteps)
    RUN/camera_colours.json       learned camera colours (camera id → affine matrix and offset)
    RUN/cameras_landmarks.json    cameras solved from landmarks (a run that started from them)
    RUN/.lock                     the one writer's lock (holds its pid)
"""

RUN_FORMAT = "mogaface-run"
RUN_VERSION = 1

CONFIG_FILE = "config.toml"
HEAD_STEM = "head"  # + the capture's model suffix (.pkl, .npz)
RUN_FILE = "run.json"
EVENTS_FILE = "events.jsonl"
REFINE_TRACKING_EVENTS_FILE = "refine_tracking_events.jsonl"
CHECKPOINT_DIR = "checkpoints"
AVATAR_FILE = "avatar.pt"
MODULES_FILE = "mogaface.pt"
FLAME_PARAM_DIR = "flame_param"
CORRECTED_DIR = "flame_param_corrected"
METRICS_TRAIN_END_FILE = "metrics_train_end.json"
REFINED_CAMERAS_FILE = "cameras_refined.json"
DELAYS_FILE = "camera_delays.json"
COLOURS_FILE = "camera_colours.json"
LANDMARK_CAMERAS_FILE = "cameras_landmarks.json"
LOCK_FILE = ".lock"
