"""``bench --compare-with``: the reference commit's code is what its side imports (under the package's
name), this side runs the working tree as it is, the temporary worktree goes away, and the ratios are
this tree's figures over the reference's."""

import subprocess

import pytest

from mogaface.bench import compare


def _git(root, *args):
    subprocess.run(["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                   check=True, capture_output=True)


@pytest.fixture
def repo(tmp_path):
    """A repository whose root is a package with ``fake.py``: committed as X = 1, then X = 2, and
    X = 3 uncommitted."""
    root = tmp_path / "repo"
    root.mkdir()
    (root / "__init__.py").write_text("")
    _git(root, "init", "-q")
    for value in (1, 2):
        (root / "fake.py").write_text(f"X = {value}\nY = 0\n\ndef run(a):\n    return {{'v': a * X + Y}}\n")
        _git(root, "add", "-A")
        _git(root, "commit", "-q", "-m", f"x{value}")
    (root / "fake.py").write_text((root / "fake.py").read_text().replace("X = 2", "X = 3"))
    return root


def test_each_side_imports_its_own_tree_and_the_worktree_is_removed(repo):
    with compare.checkouts(str(repo), "HEAD~1") as (head, reference, commit):
        ours = compare.run_side(head, "mogaface.fake", "run", [5], {}, {})
        theirs = compare.run_side(reference, "mogaface.fake", "run", [5], {}, {"Y": 100})
    assert ours["v"] == 15 and theirs["v"] == 105  # working tree (X = 3); HEAD~1 (X = 1) with Y patched
    assert ours["code"].startswith(head) and theirs["code"].startswith(reference)
    assert len(ours["load_average_1min_before_after"]) == 2
    listed = subprocess.run(["git", "-C", str(repo), "worktree", "list"], capture_output=True, text=True).stdout
    assert len(listed.strip().splitlines()) == 1
    assert len(commit) == 40


def test_an_unknown_reference_is_an_error_naming_it(repo):
    with pytest.raises(ValueError, match="no-such-ref"):
        with compare.checkouts(str(repo), "no-such-ref"):
            pass


def test_splat_figures_split_the_backward_out():
    got = compare.figures("splat", {"forward_ms": 20.0, "fwd_bwd_ms": 50.0})
    assert got == {"forward_ms": 20.0, "backward_ms": 30.0, "fwd_bwd_ms": 50.0, "backward_over_forward": 1.5}
    step = {"results": [{"variant": "freeze", "gaussians": 7, "step_ms": 9.0, "stages_ms": {"render": 4.0}}]}
    assert compare.figures("step", step) == {"freeze 7: step_ms": 9.0, "freeze 7: render": 4.0}
    assert compare.figures("train", {"it_s": 0.6}) == {"it_s": 0.6}
