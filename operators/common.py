"""What every MoGaFace operator shares: the dependency gate and error reporting."""

from __future__ import annotations

from .dependencies import interpreter, missing_modules, report


def core_or_report(operator, context):
    """``core.scene_conversion`` if the core's packages import here, else report and return None."""
    missing = missing_modules()
    if missing:
        operator.report({"ERROR"}, report(missing, interpreter(context)))
        return None
    from ..core import scene_conversion

    return scene_conversion


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


def clear_status_text() -> None:
    """Take a job's progress off every window's status bar (a job ends, or the extension goes)."""
    import bpy

    for window in getattr(bpy.context.window_manager, "windows", ()):
        window.workspace.status_text_set(None)
        for area in window.screen.areas:  # the status bar redraws with the next redraw of the window
            area.tag_redraw()
