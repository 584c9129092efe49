"""The pinned packages the core needs inside Blender, and the pip command that installs them.

Blender-free: the add-on's "Install Dependencies" operator calls :func:`install`; nothing is
read or imported at import time.
"""

from __future__ import annotations

import subprocess

# Same pins as requirements.txt (tests check they agree).
PINNED = (
    "torch==2.13.0",
    "numpy==1.26.4",
    "numba==0.68.1",
    "llvmlite==0.50.0",
    "scipy==1.17.1",
    "scikit-image==0.26.0",
    "trimesh==5.2.0",
    "OpenEXR==3.5.3",
    "pillow==13.0.0",
)

INSTALL_TIMEOUT_S = 3600.0


def requirements() -> list[str]:
    """The pinned requirement lines, e.g. ``torch==2.13.0``."""
    return list(PINNED)


def install_command(python: str, target: str) -> list[str]:
    """argv that pip-installs the pinned packages for ``python`` into the folder ``target``."""
    return [str(python), "-m", "pip", "install", "--disable-pip-version-check", "--no-input",
            "--upgrade", "--target", str(target), *requirements()]


def install(python: str, target: str, timeout: float = INSTALL_TIMEOUT_S, lines: int = 5) -> tuple[bool, str]:
    """Run the install in a child process; (success, message), the message ends with pip's last stderr lines."""
    try:
        result = subprocess.run(install_command(python, target), capture_output=True, text=True,
                                timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return False, f"pip did not finish within {timeout:.0f} s"
    except OSError as error:
        return False, f"Cannot run {python}: {error.strerror or error}"
    if result.returncode == 0:
        return True, f"Installed {len(PINNED)} packages into {target}"
    tail = [line for line in (result.stderr or result.stdout).splitlines() if line.strip()][-lines:]
    return False, f"pip failed (exit {result.returncode}): " + " | ".join(tail)
