"""Find, verify and install MediaPipe's face models (Apache-2.0), offline.

Four TFLite files from the ``mediapipe==0.10.14`` wheel (its CPython 3.11 manylinux build, pinned
by sha256 in ``requirements-weights.txt``; downloaded, never installed): the short-range face
detector, the 468-point face mesh, the iris model and the selfie (person) segmentation. They run
on ``ai_edge_litert``'s interpreter, which has wheels for Python 3.11 and 3.13 (the mediapipe
wheel has no 3.13 build, and would pull OpenCV and protobuf).

The mesh model with attention (``face_landmark_with_attention.tflite``, 478 points with irises)
is in the same wheel but needs MediaPipe's own TFLite operators (``Landmarks2TransformMatrix``
and others), which a plain interpreter lacks; the irises come from the iris model instead, as in
MediaPipe's iris-tracking graph.

Set-up (``scripts/ensure_venv.sh``) downloads the wheel and runs
``python -m mogaface.core.track.models install mediapipe-0.10.14-….whl``, which copies the four
files into ``<sys.prefix>/share/mogaface/face/``; Blender's *Install Dependencies* puts them in
``<site-packages>/mogaface_weights/face/``. ``MOGAFACE_FACE_MODELS`` names another folder.
Where else they are looked for, and how they are checked: :mod:`..weights`.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

from .. import weights
from ..errors import InputError

ENV_VAR = "MOGAFACE_FACE_MODELS"
SET = "face"
WHEEL = "mediapipe==0.10.14"
WHEEL_NAME = "mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
PACKAGED_FOLDER = weights.packaged_folder(SET)

_MODULES = "mediapipe/modules/"
#: The four models by role: the file name, its sha256 and where the wheel holds it.
MODELS = {
    "detector": weights.PinnedFile(
        "face_detection_short_range.tflite", "bbff11cebd1eb27a1e004cae0b0e63ec8c551cbf34a4451148b4908b8db3eca8",
        _MODULES + "face_detection/face_detection_short_range.tflite"),
    "landmarks": weights.PinnedFile(
        "face_landmark.tflite", "1055cb9d4a9ca8b8c688902a3a5194311138ba256bcc94e336d8373a5f30c814",
        _MODULES + "face_landmark/face_landmark.tflite"),
    "iris": weights.PinnedFile(
        "iris_landmark.tflite", "d1744d2a09c25f501d39eba4faff47e53ecca8852c5ce19bce8eeac39357521f",
        _MODULES + "iris_landmark/iris_landmark.tflite"),
    "segmentation": weights.PinnedFile(
        "selfie_segmentation.tflite", "9ee168ec7c8f2a16c56fe8e1cfbc514974cbbb7e434051b455635f1bd1462f5c",
        _MODULES + "selfie_segmentation/selfie_segmentation.tflite"),
}

HOW_TO_GET = (
    "in Blender, click Install Dependencies in the MoGaFace panel; from a checkout, "
    "run `bash scripts/ensure_venv.sh` (it downloads the pinned mediapipe wheel and installs the models); "
    f"or `pip download {WHEEL} --no-deps --only-binary :all: --platform manylinux2014_x86_64 "
    "--python-version 3.11` and `python -m mogaface.core.track.models install mediapipe-0.10.14-*.whl`, "
    f"or set {ENV_VAR} to a folder holding the four files"
)


def default_dir() -> pathlib.Path:
    """Where set-up puts the models: inside the environment, beside its packages."""
    return weights.share_dir(SET)


def search_dirs() -> list[pathlib.Path]:
    """Where the models are looked for when ``$MOGAFACE_FACE_MODELS`` is not set, in order."""
    return [default_dir(), *weights.packaged_dirs(SET), weights.user_cache_dir(SET)]


def _folder() -> pathlib.Path | None:
    """The folder the models are taken from: the override, else the first that has them all."""
    override = os.environ.get(ENV_VAR)
    if override:
        return pathlib.Path(override)
    return next((folder for folder in search_dirs()
                 if all((folder / pinned.name).is_file() for pinned in MODELS.values())), None)


def installed() -> bool:
    """Whether the four files are where they are looked for (no hash check: cheap enough for a panel)."""
    folder = _folder()
    return folder is not None and all((folder / pinned.name).is_file() for pinned in MODELS.values())


def find(role: str) -> pathlib.Path:
    """The verified model file of ``role`` (a key of :data:`MODELS`)."""
    pinned = MODELS[role]
    folder = _folder()
    if folder is None:
        looked = ", ".join(str(folder) for folder in search_dirs())
        raise InputError(None, None, f"MediaPipe's face models not found (looked in {looked}); {HOW_TO_GET}")
    path = folder / pinned.name
    if not path.is_file():
        named = f" (named by {ENV_VAR})" if os.environ.get(ENV_VAR) else ""
        raise InputError(path, None, f"face model not found{named}; {HOW_TO_GET}")
    return weights.verified(path, pinned.sha256, f"not MediaPipe's {role} model of {WHEEL} ({HOW_TO_GET})")


def find_all() -> dict[str, pathlib.Path]:
    """Every verified model file, by role."""
    return {role: find(role) for role in MODELS}


def install_from_wheel(wheel: str | os.PathLike, dest: str | os.PathLike | None = None) -> list[pathlib.Path]:
    """Copy the four models out of the mediapipe wheel into ``dest`` (default :func:`default_dir`),
    each checked against its pinned sha256 before any is written."""
    dest = pathlib.Path(dest) if dest is not None else default_dir()
    return weights.install_members(wheel, MODELS.values(), dest, f"the {WHEEL} wheel")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mogaface.core.track.models", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    install = commands.add_parser("install", help="install the models from the mediapipe wheel")
    install.add_argument("wheel", help=f"path of {WHEEL_NAME}")
    install.add_argument("--dest", default=None, help=f"target folder (default: {default_dir()})")
    check = commands.add_parser("check", help="exit 0 if the folder holds the four verified files")
    check.add_argument("--dest", default=None, help=f"folder to check (default: {default_dir()})")
    commands.add_parser("where", help="print the verified model paths, or why they cannot be used")
    args = parser.parse_args(argv)
    try:
        if args.command == "install":
            for path in install_from_wheel(args.wheel, args.dest):
                print(path)
        elif args.command == "check":
            folder = args.dest or default_dir()
            for path in weights.check_folder(folder, {m.name: m.sha256 for m in MODELS.values()}, HOW_TO_GET):
                print(path)
        else:
            for path in find_all().values():
                print(path)
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
