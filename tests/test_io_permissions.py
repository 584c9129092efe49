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


# -- what an output may replace ---------------------------------------------------------------

import socket

from mogaface.core.errors import InputError
from mogaface.core.io.atomic import atomic_open, open_for_append


def _fifo(path):
    os.mkfifo(path)


def _socket(path):
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    return server


@pytest.mark.parametrize("make, words", [(_fifo, "FIFO"), (lambda p: p.mkdir(), "folder"),
                                         (_socket, "socket"), (lambda p: p.symlink_to("/dev/null"), "character device"),
                                         (lambda p: p.symlink_to(p.parent), "link to a folder")])
def test_an_output_never_replaces_what_is_not_a_file(tmp_path, make, words):
    target = tmp_path / "out.json"
    kept = make(target)
    before = os.lstat(target)
    with pytest.raises(InputError, match=words) as raised:
        write_json(target, {"a": 1})
    assert str(target) in str(raised.value)
    after = os.lstat(target)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]
    if kept is not None:
        kept.close()


def test_a_link_to_a_file_is_replaced_as_the_link_and_the_file_it_named_is_kept(tmp_path):
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text("mine")
    link = tmp_path / "out.json"
    link.symlink_to(elsewhere)
    write_json(link, {"a": 1})
    assert not link.is_symlink() and '"a": 1' in link.read_text()
    assert elsewhere.read_text() == "mine"


def test_a_dangling_link_is_replaced_never_followed(tmp_path):
    link = tmp_path / "out.json"
    link.symlink_to(tmp_path / "missing" / "target.json")
    write_json(link, {"a": 1})
    assert not link.is_symlink() and not (tmp_path / "missing").exists()


def test_a_target_that_becomes_a_fifo_while_writing_is_not_replaced(tmp_path):
    target = tmp_path / "out.bin"
    with pytest.raises(InputError, match="FIFO"):
        with atomic_open(target) as handle:
            handle.write(b"x")
            os.mkfifo(target)
    assert stat.S_ISFIFO(os.lstat(target).st_mode)
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]


@pytest.mark.parametrize("make, words", [(_fifo, "FIFO"), (lambda p: p.symlink_to("/dev/null"), "character device"),
                                         (lambda p: p.symlink_to(p.parent / "file"), "symbolic link")])
def test_a_log_is_appended_to_a_regular_file_only(tmp_path, make, words):
    (tmp_path / "file").write_text("mine\n")
    target = tmp_path / "events.jsonl"
    make(target)
    with pytest.raises(InputError, match=words):
        open_for_append(target)  # never blocks on the FIFO either
    assert (tmp_path / "file").read_text() == "mine\n"


def test_a_log_grows(tmp_path):
    for line in ("a", "b"):
        with open_for_append(tmp_path / "log") as handle:
            handle.write(line + "\n")
    assert (tmp_path / "log").read_text() == "a\nb\n"
