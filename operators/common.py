"""What every MoGaFace operator shares: the dependency gate, error reporting, background threads."""

from __future__ import annotations

from .dependencies import REQUIRED_MODULES, missing_modules, report


def dependencies_ready(operator, context, needs=REQUIRED_MODULES) -> bool:
    """True if the packages ``needs`` import here, else report which are missing and return False.

    Reading files needs numpy only (``dependencies.FILE_MODULES``); training and the avatar need torch.
    """
    missing = missing_modules(needs)
    if missing:
        operator.report({"ERROR"}, report(missing))
        return False
    return True


def run_core(operator, function, *args, **kwargs):
    """Call a core function; the project's errors (bad files) become an error report and None."""
    from ..core.errors import MogafaceError

    try:
        return function(*args, **kwargs)
    except MogafaceError as error:
        operator.report({"ERROR"}, str(error))
    except OSError as error:
        operator.report({"ERROR"}, f"{getattr(error, 'filename', None) or ''}: {error.strerror or error}")
    return None


def redraw_areas(context, types=("VIEW_3D",)) -> None:
    """Redraw every area of these types in every window (a job's progress changed)."""
    for window in getattr(context.window_manager, "windows", ()):
        for area in window.screen.areas:
            if area.type in types:
                area.tag_redraw()


def clear_status_text() -> None:
    """Take a job's progress off every window's status bar (a job ends, or the extension goes)."""
    import bpy

    for window in getattr(bpy.context.window_manager, "windows", ()):
        window.workspace.status_text_set(None)
        for area in window.screen.areas:  # the status bar redraws with the next redraw of the window
            area.tag_redraw()


_threads: dict = {}


def background_thread(kind: str):
    """The one worker thread of a kind of work (``render``: renders and avatar loads; ``viewport``: the
    CPU image; ``posing``: the GPU draw's splats), started when first needed; an executor."""
    if kind not in _threads:
        import concurrent.futures

        _threads[kind] = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"mogaface-{kind}")
    return _threads[kind]


def stop_background_threads() -> None:
    """End every :func:`background_thread` (the extension is disabled): queued work is dropped and
    running work ends on its own; nothing of the extension stays in Blender's process."""
    for pool in _threads.values():
        pool.shutdown(wait=False, cancel_futures=True)
    _threads.clear()


class OpensFileBrowser:
    """Mixin for operators with a ``filepath``: run at once when a path is given (scripts, the
    panel's file field), else open the file browser first (at ``suggested_name`` when set)."""

    suggested_name = ""

    def invoke(self, context, event):
        if self.filepath:
            return self.execute(context)
        if self.suggested_name:
            self.filepath = self.suggested_name
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}
