"""Which Python packages the core needs, whether they import here, and how to install them.

Checked with ``importlib.util.find_spec`` (nothing is imported), so the panel can draw the
answer on every redraw, and the operators can refuse cleanly instead of failing in an import.
"""

from __future__ import annotations

import importlib.util
import sys

REQUIRED_MODULES = ("numpy", "torch", "numba")


def missing_modules(names=REQUIRED_MODULES) -> list[str]:
    """The names among ``names`` that this Python cannot import."""
    missing = []
    for name in names:
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):  # a broken entry in sys.modules counts as missing
            found = False
        if not found:
            missing.append(name)
    return missing


def install_command(missing, python: str | None = None) -> str:
    """The pip command that installs ``missing`` for the interpreter ``python``."""
    python = python or sys.executable
    return f'"{python}" -m pip install {" ".join(missing)}'


def report(missing, python: str | None = None) -> str:
    """One sentence for an operator's error report: what is missing and how to fix it."""
    return f"Missing Python packages: {', '.join(missing)}. Install them with: {install_command(missing, python)}"


def top_package() -> str:
    """The extension's own module name (``mogaface`` or ``bl_ext.<repo>.mogaface``)."""
    return __package__.rpartition(".")[0]


def interpreter(context) -> str:
    """The Python interpreter named in the add-on preferences (this one if unset)."""
    addon = context.preferences.addons.get(top_package())
    path = getattr(getattr(addon, "preferences", None), "python_path", "") if addon else ""
    return path or sys.executable
