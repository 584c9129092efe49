"""How worker processes start, and numba's cache folder: only the intended code is ever loaded.

A worker (``python -m mogaface`` started by Blender) must import this package folder under the
name ``mogaface`` and the extension's installed packages, and nothing from its working directory,
``PYTHONPATH`` or beside the package folder. Two processes importing the code under different
names (Blender's ``bl_ext.<repo>.mogaface``, the worker's ``mogaface``) keep separate numba caches,
in folders nobody else can write (numba loads them with pickle).
"""

import json
import os
import pathlib
import shutil
import stat
import subprocess
import sys
import warnings

import pytest

from mogaface.core import numba_cache
from mogaface.core.for_blender.worker import package_root, train_command, worker_command, worker_environment

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run_environment(tmp_path, paths=(), env=None, extra=()):
    """The worker's own account of what it imports (``python -m mogaface environment``)."""
    command = worker_command(sys.executable, ["environment", *extra], paths)
    result = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=120,
                            env=worker_environment(env))
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_worker_imports_the_package_folder_and_the_given_paths_only(tmp_path):
    site = tmp_path / "site-packages"
    (site / "mogaface_probe_installed").mkdir(parents=True)
    (site / "mogaface_probe_installed" / "__init__.py").write_text("")
    (tmp_path / "mogaface_probe_cwd.py").write_text("")  # the working directory
    elsewhere = tmp_path / "pythonpath"
    elsewhere.mkdir()
    (elsewhere / "mogaface_probe_env.py").write_text("")
    env = dict(os.environ, PYTHONPATH=str(elsewhere), NUMBA_CACHE_DIR=str(tmp_path / "inherited"))
    probes = ["--module", "mogaface_probe_installed", "--module", "mogaface_probe_cwd", "--module", "mogaface_probe_env"]
    seen = run_environment(tmp_path, [site], env, probes)
    assert seen["package"] == "mogaface" and pathlib.Path(seen["package_folder"]) == package_root()
    assert seen["sys_path"][0] == str(site)
    assert seen["modules"]["mogaface_probe_installed"] == str(site / "mogaface_probe_installed" / "__init__.py")
    assert seen["modules"]["mogaface_probe_cwd"] is None and seen["modules"]["mogaface_probe_env"] is None
    assert str(tmp_path) not in seen["sys_path"] and "" not in seen["sys_path"]
    assert str(package_root().parent) not in seen["sys_path"]  # nothing beside the package folder
    assert seen["numba_cache"].endswith(os.path.join("numba", "mogaface"))  # its own, not the parent's


def test_train_command_is_an_isolated_worker(tmp_path):
    command = train_command("/py", tmp_path / "cap", tmp_path / "run", preset="quick", steps=5, paths=["/site"])
    assert command[:4] == ["/py", "-I", "-u", "-c"]
    spec = json.loads(command[5])
    assert spec["path"] == ["/site"] and spec["name"] == "mogaface" and spec["root"] == str(package_root())
    assert command[6:] == ["train", str(tmp_path / "cap"), "--out", str(tmp_path / "run"), "--quiet",
                           "--preset", "quick", "--steps", "5"]
    timed = train_command("/py", "cap", "run", preset="quick", minutes=90)
    assert timed[-4:] == ["--preset", "quick", "--minutes", "90"]
    assert "--minutes" not in train_command("/py", "cap", "run", resume=True, minutes=90)  # a run keeps its own
    rounds = train_command("/py", "cap", "run", preset="quick", camera_rounds=3)
    assert rounds[-4:] == ["--preset", "quick", "--refine-cameras", "3"]
    assert "--refine-cameras" not in train_command("/py", "cap", "run", resume=True, camera_rounds=3)
    landmarks = train_command("/py", "cap", "run", camera_rounds=3, cameras_from_landmarks=True)
    assert landmarks[-4:] == ["--refine-cameras", "3", "--cameras-start", "landmarks"]
    assert "--cameras-start" not in train_command("/py", "cap", "run", camera_rounds=0, cameras_from_landmarks=True)
    assert "--cameras-start" not in train_command("/py", "cap", "run", resume=True, camera_rounds=3,
                                                  cameras_from_landmarks=True)
    measured = train_command("/py", "cap", "run", camera_rounds=3, centres_measured=True)
    assert measured[-4:] == ["--refine-cameras", "3", "--camera-gauge", "none"]
    assert "--camera-gauge" not in train_command("/py", "cap", "run", centres_measured=True)  # no refinement
    assert train_command("/py", "cap", "run", camera_delays=True)[-1] == "--camera-delays"
    assert "--camera-delays" not in train_command("/py", "cap", "run", resume=True, camera_delays=True)


def test_refine_cameras_on_the_command_line_sets_the_rounds():
    import argparse

    from mogaface.core.cli import train as train_cli
    from mogaface.core.train import config as C

    parser = argparse.ArgumentParser()
    train_cli.add_arguments(parser)
    for flags, rounds in ((["--refine-cameras"], 1), (["--refine-cameras", "3"], 3)):
        config = C.resolve("quick", overrides=train_cli._overrides(parser.parse_args(["cap", "--out", "r", *flags])))
        assert config.cameras.refine and config.cameras.rounds == rounds
    assert not C.resolve(overrides=train_cli._overrides(parser.parse_args(["cap", "--out", "r"]))).cameras.refine
    gauge = train_cli._overrides(parser.parse_args(["cap", "--out", "r", "--refine-cameras", "--camera-gauge", "none"]))
    assert C.resolve(overrides=gauge).cameras.gauge == "none"
    assert C.resolve(overrides=train_cli._overrides(parser.parse_args(["cap", "--out", "r"]))).cameras.gauge == "rigid"


def test_python_dash_m_drops_the_working_directory(tmp_path):
    (tmp_path / "mogaface_probe_cwd.py").write_text("")
    result = subprocess.run([sys.executable, "-m", "mogaface", "environment", "--module", "mogaface_probe_cwd"],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout)
    assert seen["modules"]["mogaface_probe_cwd"] is None and str(tmp_path) not in seen["sys_path"]


# -- numba's cache ---------------------------------------------------------------------------------
def test_cache_folders_are_per_import_name_and_owner_only(tmp_path, monkeypatch):
    monkeypatch.setenv(numba_cache.CACHE_ENV, str(tmp_path / "cache"))
    worker = numba_cache.folder_for("mogaface")
    blender = numba_cache.folder_for("bl_ext.user_default.mogaface")
    assert worker != blender and worker.parent == blender.parent == tmp_path / "cache" / "numba"
    assert numba_cache.private_folder(blender) == blender
    for folder in (blender, blender.parent, blender.parent.parent):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder


def test_a_folder_others_can_write_is_refused(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    (tmp_path / "elsewhere").mkdir()
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "elsewhere")
    for folder, reason in ((shared, "other users can write it"), (link, "not a plain folder")):
        assert reason in numba_cache.unsafe_reason(folder)
        with pytest.warns(RuntimeWarning, match=reason):
            used = numba_cache.private_folder(folder)
        assert used != folder and stat.S_IMODE(used.stat().st_mode) == 0o700
        used.rmdir()
    assert stat.S_IMODE(shared.stat().st_mode) == 0o777  # left as it was
    if os.getuid() == 0:  # root can hand a folder to another user
        foreign = tmp_path / "foreign"
        foreign.mkdir(mode=0o700)
        os.chown(foreign, 65534, 65534)
        assert "belongs to user id 65534" in numba_cache.unsafe_reason(foreign)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert numba_cache.private_folder(tmp_path / "fresh") == tmp_path / "fresh"


KERNEL_UNDER_A_NAME = """
import importlib, importlib.util, json, sys, types
root, name = sys.argv[1], sys.argv[2]
parts = name.split(".")
for i in range(1, len(parts)):  # the parents of bl_ext.<repo>.mogaface, as Blender makes them
    sys.modules.setdefault(".".join(parts[:i]), types.ModuleType(".".join(parts[:i])))
spec = importlib.util.spec_from_file_location(name, root + "/__init__.py", submodule_search_locations=[root])
module = importlib.util.module_from_spec(spec)
sys.modules[name] = module
spec.loader.exec_module(module)
import numpy as np
raster = importlib.import_module(name + ".core.data.mesh_raster")
counts, tris = raster.bin_to_bands(np.array([[0, 10, 0, 3]], np.int64), 2)
import os
print(json.dumps({"counts": counts.tolist(), "hits": sum(raster.bin_to_bands.stats.cache_hits.values()),
                  "cache": os.environ["NUMBA_CACHE_DIR"]}))
"""


def test_two_import_names_never_load_each_others_numba_cache(tmp_path):
    env = dict(os.environ, **{numba_cache.CACHE_ENV: str(tmp_path / "cache")})
    env.pop("NUMBA_CACHE_DIR", None)

    def run(name):
        result = subprocess.run([sys.executable, "-I", "-c", KERNEL_UNDER_A_NAME, str(ROOT), name],
                                capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
        assert result.returncode == 0, result.stderr[-2000:]
        return json.loads(result.stdout)

    blender, worker = "bl_ext.user_default.mogaface", "mogaface"
    first = [run(blender), run(worker)]  # each compiles into its own folder
    again = [run(worker), run(blender)]  # and loads only its own files
    assert [r["hits"] for r in first] == [0, 0] and all(r["hits"] > 0 for r in again)
    assert {r["cache"] for r in first} == {str(numba_cache.folder_for(n, tmp_path / "cache")) for n in (blender, worker)}
    assert all(r["counts"] == first[0]["counts"] for r in again)
    for name in (blender, worker):
        assert list(numba_cache.folder_for(name, tmp_path / "cache").rglob("*.nbi")), name


def test_copies_of_the_same_code_share_its_kernels_and_a_changed_folder_compiles_again(tmp_path):
    """The cache is filed by the code, not by where it lies (core/numba_locator.py): a second
    install of the same code loads the first one's kernels; a change anywhere in the kernel's folder
    (its neighbours are inlined) compiles it again."""
    env = dict(os.environ, **{numba_cache.CACHE_ENV: str(tmp_path / "cache")})
    env.pop("NUMBA_CACHE_DIR", None)

    def copy_of_the_package(where):
        (where / "core").mkdir(parents=True)
        shutil.copy(ROOT / "__init__.py", where / "__init__.py")
        shutil.copytree(ROOT / "core", where / "core", dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
        return where

    def hits(root):
        result = subprocess.run([sys.executable, "-I", "-c", KERNEL_UNDER_A_NAME, str(root), "mogaface"],
                                capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
        assert result.returncode == 0, result.stderr[-2000:]
        return json.loads(result.stdout)["hits"]

    first, second = copy_of_the_package(tmp_path / "a"), copy_of_the_package(tmp_path / "b")
    assert hits(first) == 0 and hits(second) > 0  # compiled once, by the first copy
    beside = second / "core" / "data" / "paths.py"  # not the kernel's file: a module of its folder
    beside.write_text(beside.read_text() + "\n# changed\n")
    assert hits(second) == 0 and hits(first) == 0  # each change of the folder's code compiles again
    filed = numba_cache.folder_for("mogaface", tmp_path / "cache") / "package" / "core" / "data"
    assert list(filed.glob("mesh_raster.bin_to_bands-*.nbi"))  # under its folder in the package


def test_the_progress_bar_text_fits_the_sidebar_and_says_compiling_until_timed():
    """The sidebar at its default width shows about 30 characters of a progress bar before Blender
    cuts the middle out ("loss 0.…R 16.19 dB"): the bar holds the step and the ETA, the line
    below the loss and PSNR."""
    from mogaface.core.for_blender.worker import Progress

    starting = Progress(state="running", step=0, steps=1500)
    assert starting.bar_text() == "step 0/1500 · compiling"
    timing = Progress(state="running", step=10, steps=1500, loss=0.0512, psnr=16.19)
    assert timing.bar_text() == "step 10/1500 · timing"
    running = Progress(state="running", stage="round 2", step=14999, steps=15000, loss=0.0234, psnr=32.19, eta_s=828)
    assert running.bar_text() == "round 2 14999/15000 · ETA 13:48" and len(running.bar_text()) <= 32
    assert running.detail_text() == "loss 0.0234, PSNR 32.19 dB"
    assert running.text() == "round 2 14999/15000, ETA 13:48, loss 0.0234, PSNR 32.19 dB"
