"""Files the project writes get the permissions ``open`` would give them (0666 less the umask)."""

import os
import stat

import numpy as np
import pytest

from mogaface.core.io.atomic import write_json
from mogaface.core.io.image import write_exr, write_png


@pytest.mark.parametrize("umask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_written_files_follow_the_umask(tmp_path, umask, expected):
    old = os.umask(umask)
    try:
        write_json(tmp_path / "run.json", {"a": 1})
        write_png(tmp_path / "frame.png", np.zeros((4, 4, 3), np.float32))
        write_exr(tmp_path / "frame.exr", np.zeros((4, 4, 3), np.float32))
        with open(tmp_path / "plain.txt", "w") as handle:  # what open() itself gives, for reference
            handle.write("x")
    finally:
        os.umask(old)
    for name in ("run.json", "frame.png", "frame.exr", "plain.txt"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == expected, name
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]
