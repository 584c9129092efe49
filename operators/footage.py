"""``mogaface.track_footage``, ``mogaface.drive_from_footage`` and their Cancel: the artist's own clip.

Track Footage runs ``python -m mogaface track`` in a child process (progress, ETA and Cancel as
training has them; Blender never blocks), then does what Import Capture, Import Head and Import
Tracking do: the camera, the head keyed with the tracked parameters, the footage as the camera's
background (a video plays frame by frame as a Movie Clip), framed; frames where the face was lost
become timeline markers. Several videos picked at once are one capture: each its own camera with
its clip behind it, the scene's camera switching at each clip's first frame (a marker bound to
it). Drive from Footage runs ``python -m mogaface drive`` with the chosen head's shape held fixed
and keys its expressions, jaw, eyes and head pose, thinned within a tolerance, at the scene's
frame rate. One footage job runs at a time, like every child job.
"""

from __future__ import annotations

import os
import shutil
import tempfile

import bpy
from bpy.props import BoolProperty, CollectionProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from .common import dependencies_ready, run_core
from .dependencies import FILE_MODULES, interpreter, worker_paths
from .handlers.heads import is_head
from .import_tracking import head_or_report, key_tracking
from .jobs import FollowsChildJob, cancel_operator, end_job, job_progress, new_job, refuse_if_busy
from .train import preferred_threads

#: The one running footage job (tracking or driving).
_job = new_job("tracking the footage")

LOST_MARKER = "no face"
#: Markers bound to each clip's camera at its first frame (several videos): "clip 2: IMG_0043.MOV".
CLIP_MARKER = "clip"


def current_worker():
    return _job["worker"]


def last_progress():
    return job_progress(_job)


def footage_paths(operator) -> list[str]:
    """What the operator was given: a Movie Clip of the file, the files picked in the browser, or
    one path (a video, a photo folder)."""
    if operator.movie_clip:
        clip = bpy.data.movieclips.get(operator.movie_clip)
        return [bpy.path.abspath(clip.filepath, library=clip.library)] if clip is not None else []
    directory = bpy.path.abspath(operator.directory) if operator.directory else ""
    names = [item.name for item in operator.files if item.name]
    if directory and names:
        return [os.path.join(directory, name) for name in names]
    if operator.filepath:
        return [bpy.path.abspath(operator.filepath)]
    return [directory] if directory else []


def remove_markers(scene, prefix: str) -> None:
    """The timeline markers a tracking placed (their names start with ``prefix``): a new one replaces them."""
    for marker in [m for m in scene.timeline_markers if m.name.startswith(prefix)]:
        scene.timeline_markers.remove(marker)


def mark_lost_frames(scene, frames, label: str = LOST_MARKER) -> None:
    """Timeline markers at ``frames`` (scene frames where the tracker lost the face); earlier ones go."""
    remove_markers(scene, label)
    for frame in frames:
        scene.timeline_markers.new(label, frame=int(frame))


def lost_text(lost: list[int]) -> str:
    from ..core.for_blender.axes import FRAME_OFFSET

    if not lost:
        return ""
    shown = ", ".join(str(t + FRAME_OFFSET) for t in lost[:8]) + (", …" if len(lost) > 8 else "")
    return f"; no face in {len(lost)} frames ({shown}: marked on the timeline, interpolated)"


def clips_text(report: dict) -> str:
    clips = report.get("clips") or []
    return f" of {len(clips)} clips (a camera each, the scene's switching at each clip's marker)" if clips else ""


def use_clip_fps(scene, fps: float) -> None:
    """The scene plays at the footage's rate (a tracked frame per scene frame)."""
    if fps and fps > 0:
        whole = max(1, round(fps))
        scene.render.fps, scene.render.fps_base = whole, whole / fps


def show_movie_behind(camera_object, path: str, first_frame: int, first_timestep: int = 0):
    """The video ``path`` as the camera's background, frame by frame: its frame ``first_frame`` on
    timestep ``first_timestep``'s scene frame."""
    from ..core.for_blender.axes import FRAME_OFFSET

    clip = bpy.data.movieclips.load(path, check_existing=True)
    clip.frame_start = FRAME_OFFSET + int(first_timestep) - int(first_frame)
    data = camera_object.data
    data.background_images.clear()
    background = data.background_images.new()
    background.source = "MOVIE_CLIP"
    background.clip = clip
    background.use_camera_clip = False
    background.frame_method = "STRETCH"
    background.alpha = 1.0
    data.show_background_images = True
    return clip


def show_clips(scene, report: dict) -> None:
    """Several videos tracked together: each clip behind its camera, and a marker bound to that
    camera at the clip's first timestep, so the scene's camera follows the footage."""
    from ..core.for_blender.axes import FRAME_OFFSET
    from .import_capture import COLLECTION_NAME, capture_cameras

    remove_markers(scene, CLIP_MARKER + " ")
    cameras = capture_cameras(bpy.data.collections.get(COLLECTION_NAME))
    first = 0
    for number, clip in enumerate(report["clips"]):
        camera = cameras.get(clip["camera"])
        if camera is not None and clip["frames"]:
            show_movie_behind(camera, clip["source"], report["input_frames"][first], first)
            marker = scene.timeline_markers.new(f"{CLIP_MARKER} {number + 1}: {os.path.basename(clip['source'])}",
                                                frame=FRAME_OFFSET + first)
            marker.camera = camera
        first += clip["frames"]


class _FootageJob(ImportHelper, FollowsChildJob):
    """What both operators share: the footage they are given (Blender's import file browser: one or
    several files, or a folder), the child they start."""

    filepath: StringProperty(name="Footage", subtype="FILE_PATH",
                             description="A video file (mp4, mov, …) or a folder of photos")
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement, options={"HIDDEN", "SKIP_SAVE"})
    filter_glob: StringProperty(default="*.mp4;*.mov;*.m4v;*.mkv;*.avi;*.webm;*.jpg;*.jpeg;*.png",
                                options={"HIDDEN"})
    movie_clip: StringProperty(name="Movie Clip", description="A Movie Clip of this file (instead of a path)")
    out: StringProperty(name="Output", subtype="DIR_PATH",
                        description="Folder to write (new or empty; empty: one beside the footage)")
    size: IntProperty(name="Size", default=512, min=64, max=4096,
                      description="Longer side of the tracked frames in pixels")
    fit_steps: IntProperty(name="Fitting Steps", default=200, min=1, max=2000, description="Iterations of the fit")
    photometric_steps: IntProperty(name="Skin Steps", default=-1, min=-1, max=10000,
                                   description="Iterations of the photometric stage, which turns the head until its "
                                               "skin looks alike from frame to frame (-1: those chosen for the "
                                               "footage, 800 for a video on every 4th frame, then 200 on every frame, and 1920 for "
                                               "photos; 0: off, minutes faster)")
    python: StringProperty(name="Python", subtype="FILE_PATH", options={"HIDDEN", "SKIP_SAVE"},
                           description="Interpreter for the child process (empty: the preferences')")
    job_folder: StringProperty(options={"HIDDEN", "SKIP_SAVE"})

    def invoke(self, context, event):
        if self.movie_clip or self.filepath:
            return self.execute(context)
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def _inputs(self, context) -> list[str] | None:
        if refuse_if_busy(self) or not dependencies_ready(self, context, needs=FILE_MODULES):
            return None
        inputs = footage_paths(self)
        missing = [path for path in inputs if not os.path.exists(path)]
        if not inputs or missing:
            self.report({"ERROR"}, f"{missing[0] if missing else 'No footage'}: pick a video file, photos or a "
                                   "folder of photos (or a Movie Clip of this file)")
            return None
        return inputs

    def _photometric_steps(self) -> int | None:
        """The stage's iterations for the child's command line (None: those chosen for the footage)."""
        return self.photometric_steps if self.photometric_steps >= 0 else None

    def _start(self, context, command_for) -> set:
        from ..core.for_blender.worker import FootageWorker

        python = bpy.path.abspath(self.python) if self.python else interpreter(context)
        self.job_folder = tempfile.mkdtemp(prefix="mogaface-footage-")
        command = command_for(python, self.job_folder, worker_paths(python))
        worker = FootageWorker(command, self.job_folder)
        try:
            worker.start()
        except OSError as error:
            shutil.rmtree(self.job_folder, ignore_errors=True)
            self.report({"ERROR"}, f"Cannot start {command[0]}: {error.strerror or error}")
            return {"CANCELLED"}
        _job["worker"], _job["last"] = worker, None
        return self.follow(context, worker)

    def _ended(self, progress) -> bool:
        """Forget the child and its job folder; True if it finished (else reported)."""
        end_job(_job, progress)
        shutil.rmtree(self.job_folder, ignore_errors=True)
        if progress.state == "done":
            return True
        self.report({"WARNING"} if progress.state == "cancelled" else {"ERROR"},
                    f"{self.bl_label}: {progress.message}")
        return False


class MOGAFACE_OT_track_footage(_FootageJob, bpy.types.Operator):
    """Track a phone video or photos of a face (a separate process), then import the camera, the head keyed
    with the tracking and the footage behind it: a capture to train on"""

    bl_idname = "mogaface.track_footage"
    bl_label = "Track Footage"
    bl_options = {"REGISTER"}

    label, tag = "tracking the footage", "track"

    def execute(self, context):
        inputs = self._inputs(context)
        if inputs is None:
            return {"CANCELLED"}
        from ..core.for_blender.worker import track_command
        from ..core.workflows.drive import folder_beside

        self.out = bpy.path.abspath(self.out) if self.out else str(folder_beside(inputs[0], "capture"))
        threads = preferred_threads(context)
        return self._start(context, lambda python, job, paths: track_command(
            python, inputs, self.out, job, size=self.size, fit_steps=self.fit_steps, threads=threads, paths=paths,
            photometric_steps=self._photometric_steps()))

    def finished(self, context, progress) -> set:
        if not self._ended(progress):
            return {"CANCELLED"}
        from ..core.for_blender.axes import FRAME_OFFSET
        from ..core.io.jsonfile import read_json_object
        from ..core.track.pipeline import REPORT_FILE

        report = run_core(self, read_json_object, os.path.join(self.out, REPORT_FILE))
        if report is None:
            return {"CANCELLED"}
        scene = context.scene
        if bpy.ops.mogaface.import_capture("EXEC_DEFAULT", filepath=self.out) != {"FINISHED"}:
            return {"CANCELLED"}
        head_file = os.path.join(self.out, report["head_model"])
        identity = os.path.join(self.out, "flame_param", "00000.npz")
        if bpy.ops.mogaface.import_head("EXEC_DEFAULT", filepath=head_file, shape_file=identity) != {"FINISHED"}:
            return {"CANCELLED"}
        head = context.view_layer.objects.active
        scene.mogaface.identity_file = identity
        if not key_tracking(self, context, head, os.path.join(self.out, "flame_param")):
            return {"CANCELLED"}
        use_clip_fps(scene, report.get("fps") or 0)
        if report.get("kind") == "video" and scene.camera is not None:
            run_core(self, show_movie_behind, scene.camera, report["source"], report["input_frames"][0])
        elif report.get("kind") == "videos":
            run_core(self, show_clips, scene, report)
        lost = report["lost_frames"]
        mark_lost_frames(scene, [t + FRAME_OFFSET for t in lost])
        scene.frame_set(scene.frame_start)
        scene.mogaface.capture_folder = self.out
        self.report({"WARNING"} if lost else {"INFO"},
                    f"Tracked {report['frames']} frames{clips_text(report)} into {self.out}: landmarks reproject to "
                    f"{report['reprojection_px']['mean']:.2f} px{lost_text(lost)}; train on it with Train")
        return {"FINISHED"}


class MOGAFACE_OT_drive_from_footage(_FootageJob, bpy.types.Operator):
    """Track a performance clip with the head's shape held fixed (a separate process) and key the head's
    expressions, jaw, eyes and pose with it, at the scene's frame rate"""

    bl_idname = "mogaface.drive_from_footage"
    bl_label = "Drive from Footage"
    bl_options = {"REGISTER", "UNDO"}

    target: StringProperty(name="Head", description="Head object to key (empty: the active object)")
    tolerance: FloatProperty(name="Tolerance", default=0.001, min=0.0, soft_max=0.1, precision=4,
                             description="Keys that linear interpolation gives within this are dropped "
                                         "(radians, metres, expression units; 0: a key every frame)")
    keep_head_still: BoolProperty(name="Keep Head Still", default=False,
                                  description="The head keeps the pose it has now: only the face moves")

    label, tag = "driving from footage", "drive"

    def _target(self, context):
        return bpy.data.objects.get(self.target) if self.target else context.active_object

    def execute(self, context):
        obj = self._target(context)
        if not head_or_report(self, obj):
            return {"CANCELLED"}
        inputs = self._inputs(context)
        if inputs is None:
            return {"CANCELLED"}
        from ..core.for_blender.head_rig import MODEL_PATH_PROPERTY
        from ..core.for_blender.worker import drive_command
        from ..core.workflows.drive import folder_beside, write_identity
        from .handlers.heads import pose_values, rig_of

        rig = run_core(self, rig_of, obj)
        if rig is None:
            return {"CANCELLED"}
        self.target = obj.name  # the head to key, whatever is active when the job ends
        self.out = bpy.path.abspath(self.out) if self.out else str(folder_beside(inputs[0], "performance"))
        render = context.scene.render
        fps, threads, head = render.fps / render.fps_base, preferred_threads(context), obj[MODEL_PATH_PROPERTY]

        def command(python, job, paths):
            identity = os.path.join(job, "identity.npz")
            write_identity(identity, rig.shape, rig.static_offset, pose_values(obj))
            return drive_command(python, inputs[0], identity, self.out, job, head=head, fps=fps,
                                 keep_head_still=self.keep_head_still, tolerance=self.tolerance, size=self.size,
                                 fit_steps=self.fit_steps, threads=threads, paths=paths,
                                 photometric_steps=self._photometric_steps())

        return self._start(context, command)

    def finished(self, context, progress) -> set:
        if not self._ended(progress):
            return {"CANCELLED"}
        from ..core.for_blender.axes import FRAME_OFFSET
        from ..core.io.jsonfile import read_json_object
        from ..core.workflows.drive import REPORT_FILE

        obj = bpy.data.objects.get(self.target)
        if not is_head(obj):
            self.report({"ERROR"}, f"The head {self.target} is gone; the performance is in {self.out}")
            return {"CANCELLED"}
        report = run_core(self, read_json_object, os.path.join(self.out, REPORT_FILE))
        if report is None or not key_tracking(self, context, obj, self.out, self.tolerance):
            return {"CANCELLED"}
        lost = report["lost_frames"]
        mark_lost_frames(context.scene, [t + FRAME_OFFSET for t in lost])
        self.report({"WARNING"} if lost else {"INFO"},
                    f"{obj.name} plays {report['frames']} frames of {os.path.basename(report['source'])} "
                    f"({report['clip_fps']:g} fps clip, {report['fps']:g} fps scene; {report['keys']} keys of "
                    f"{report['keys_dense']} within {report['tolerance']:g}){lost_text(lost)}")
        return {"FINISHED"}


MOGAFACE_OT_footage_cancel = cancel_operator(
    "mogaface.footage_cancel", "Cancel Tracking",
    "Stop tracking the footage: nothing is imported or keyed (a cancelled Track Footage resumes from its "
    "detections when started again on the same folder)",
    current_worker, "Stopping the tracking",
)
