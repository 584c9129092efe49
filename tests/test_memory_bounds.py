"""Memory stays bounded: what training keeps does not grow with the capture's length (lazy, bounded caches),
and files that declare far more than they hold are refused before anything is allocated."""

import os
import types

import numpy as np
import torch

from mogaface.core.correction.views import ViewImages


class CountingCapture:
    """Stands in for a capture: numbered frames whose images are drawn from their number."""

    def __init__(self):
        self.loads = 0

    def load_rgb(self, frame):
        self.loads += 1
        rng = np.random.default_rng(int(frame.file_path))
        return rng.random((16, 16, 3), dtype=np.float32)


def test_encoder_views_are_kept_in_memory_up_to_a_bound_then_on_disk_then_decoded_again():
    capture = CountingCapture()
    view = 3 * 8 * 8
    views = ViewImages(capture, size=8, max_bytes=5 * view, spill_bytes=20 * view)
    frames = [types.SimpleNamespace(file_path=str(i)) for i in range(40)]
    first = [views.batch([f]) for f in frames]
    assert len(views._cache) == 5 and len(views._spilled) == 20 and capture.loads == 40
    assert os.fstat(views._spill.fileno()).st_size == 20 * view  # the spill file holds exactly its bound
    again = [views.batch([f]) for f in frames]
    assert capture.loads == 40 + 15  # the 25 kept views are not decoded twice, the rest are
    assert all(torch.equal(a, b) for a, b in zip(first, again))  # and look the same from either tier
    views.close()
    assert views._spill is None and not views._spilled
    views.batch(frames[10:11])
    assert capture.loads == 56  # once closed, a spilled view is decoded again


def test_a_failed_spill_leaves_the_view_uncached(monkeypatch):
    capture = CountingCapture()
    views = ViewImages(capture, size=8, max_bytes=0, spill_bytes=10 * 3 * 8 * 8)

    def full_disk(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full_disk)
    frame = types.SimpleNamespace(file_path="3")
    first = views.batch([frame])
    assert not views._spilled and torch.equal(views.batch([frame]), first) and capture.loads == 2


# -- files that declare far more than they hold: refused before anything is allocated ----------

import json
import pathlib
import subprocess
import sys

import pytest

TESTS = pathlib.Path(__file__).resolve().parent
CAP_BYTES = 1536 * 1024 ** 2  # each file asks for 2 GiB or more; torch and the readers need ~0.8 GiB of address space

# Loads each file with the given reader under an address-space cap; prints the error and how much
# the peak resident size grew while reading it (Linux: the peak is reset through /proc/self/clear_refs).
CHILD = r"""
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[1]), int(sys.argv[1])))
import torch
from mogaface.core.avatar.avatar import Avatar
from mogaface.core.io.jsonfile import read_json_object
from mogaface.core.io.npz import load_npz
from mogaface.core.train.checkpoint import load_checkpoint
readers = {"avatar": Avatar.load, "checkpoint": load_checkpoint, "json": read_json_object, "npz": load_npz}
def kib(field):
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith(field + ":"))
results = {}
for kind, path in zip(sys.argv[2::2], sys.argv[3::2]):
    with open("/proc/self/clear_refs", "w") as refs:
        refs.write("5")  # the peak resident size starts again from the current one
    before = kib("VmRSS")
    try:
        readers[kind](path)
        outcome = ["loaded", ""]
    except Exception as error:
        outcome = [type(error).__name__, str(error)]
    results[path] = outcome + [(kib("VmHWM") - before) * 1024]
print(json.dumps(results))
"""


def _bombs(tmp_path):
    sys.path.insert(0, str(TESTS))
    import torch
    from hostile import breakers as b

    avatar = tmp_path / "avatar.pt"
    b.torch_declaring(avatar, {"format": "mogaface-avatar", "version": 1, "x": torch.zeros(100_003)}, 100_003,
                      2 ** 29, inflate=True)
    checkpoint = tmp_path / "step_000001.pt"
    b.torch_declaring(checkpoint, {"format": "mogaface-train-checkpoint", "version": 1,
                                   "x": torch.zeros(1).expand(100_003)}, 100_003, 2 ** 31 - 1)
    padded = tmp_path / "transforms_train.json"
    with open(padded, "wb") as handle:  # 600 MiB of whitespace after an object (written, not sparse)
        handle.write(b'{"frames": []}')
        block = b" " * 2 ** 24
        for _ in range(600 // 16):
            handle.write(block)
    lists = tmp_path / "run.json"  # 18 MB of '[],': 0.8 GB of Python lists once parsed
    lists.write_bytes(b'{"a": [' + b",".join([b"[]"] * 6_000_000) + b"]}")
    npz = tmp_path / "00000.npz"
    b.npz_declaring(npz, "expr", (2 ** 30,))
    members = b.zip_of_empty_members(tmp_path / "00001.npz", 400_000)  # 36 MB: 0.2 GB of zip entries once listed
    return {"avatar": ("avatar", avatar, "declares 2147"), "checkpoint": ("checkpoint", checkpoint, "(2147483647,)"),
            "padded json": ("json", padded, "a JSON file of 620757006 bytes; the limit is"),
            "json of lists": ("json", lists, "holds up to 12000001 values"),
            "npz": ("npz", npz, "declares shape (1073741824,)"),
            "npz of many members": ("npz", members, "declares 400000 zip members")}


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="measures the peak through /proc")
def test_declared_sizes_are_refused_before_allocating(tmp_path):
    import torch

    bombs = _bombs(tmp_path)
    assert all(path.stat().st_size < 8 * 2 ** 20 for kind, (reader, path, _) in bombs.items()
               if reader != "json" and kind != "npz of many members")
    control = tmp_path / "control.pt"  # a real 96 MiB checkpoint: the probe sees what loading allocates
    torch.save({"format": "mogaface-train-checkpoint", "version": 1, "x": torch.ones(24 * 2 ** 20)}, control)
    argv = [str(CAP_BYTES)] + [str(part) for reader, path, _ in bombs.values() for part in (reader, path)]
    argv += ["checkpoint", str(control)]
    result = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True,
                            timeout=300)  # a harness against hangs only
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    for kind, (_, path, words) in bombs.items():
        error, message, grown = outcome[str(path)]
        assert error == "InputError" and message.startswith(str(path)) and words in message, (kind, message)
        assert grown < 64 * 2 ** 20, (kind, grown)  # nothing of what the file declares was allocated
    assert outcome[str(control)][0] == "loaded" and outcome[str(control)][2] >= 90 * 2 ** 20
