"""The viewport's choice between the GPU draw and the CPU image, and the GPU draw's fallback
where it cannot run (here: Blender in background mode, where ``gpu`` draws nothing)."""

from __future__ import annotations

import importlib

import test_blender_addon  # noqa: F401 - sets Blender's user folders to a temporary one first

# isort: split

import pytest  # noqa: E402


@pytest.fixture(scope="module")
def handlers():
    return (importlib.import_module("mogaface.operators.handlers.viewport"),
            importlib.import_module("mogaface.operators.handlers.gpu_draw"))


@pytest.mark.parametrize("mode, gpu_ok, moving, playing, expected", [
    ("BOTH", True, True, False, True),  # navigating: the GPU
    ("BOTH", True, False, True, True),  # playing: the GPU
    ("BOTH", True, False, False, False),  # resting: the exact CPU image is asked for
    ("GPU", True, False, False, True),
    ("CPU", True, True, True, False),
    ("BOTH", False, True, True, False),  # no GPU draw here: the CPU image, always
    ("GPU", False, False, False, False),
])
def test_which_draw_is_shown(handlers, mode, gpu_ok, moving, playing, expected):
    viewport, _ = handlers
    assert viewport.gpu_first(mode, gpu_ok, moving, playing) is expected


def test_where_the_gpu_cannot_draw_the_reason_is_kept_for_the_panel(handlers):
    _, gpu_draw = handlers
    gpu_draw.clear()
    assert gpu_draw.unavailable() is None  # not tried yet
    assert gpu_draw.program() is None  # background mode: no drawing
    reason = gpu_draw.unavailable()
    assert reason and "background" in reason
    gpu_draw.clear()


@pytest.mark.parametrize("mode, software, expected", [
    ("BOTH", False, True),
    ("BOTH", True, False),  # software OpenGL: the CPU image, off the interface thread
    ("GPU", True, True),  # asked for by name: drawn all the same
    ("CPU", False, False),
])
def test_a_software_opengl_draws_the_cpu_image_in_both(handlers, monkeypatch, mode, software, expected):
    viewport, gpu_draw = handlers
    gpu_draw.clear()
    monkeypatch.setattr(gpu_draw, "software_renderer", lambda: software)
    assert viewport.gpu_allowed(mode) is expected


def test_the_software_renderer_is_asked_once_and_background_mode_is_not_one(handlers):
    _, gpu_draw = handlers
    gpu_draw.clear()
    assert gpu_draw.software_renderer() is False  # background mode: gpu.platform refuses, no draw at all
    gpu_draw._program["software"] = True
    assert gpu_draw.software_renderer() is True  # cached: never asked again per draw
    gpu_draw.clear()
