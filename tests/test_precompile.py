"""``compile-kernels``: the kernels it compiles are the ones a capture and a training run use."""

import json
import subprocess
import sys

# In a fresh process: compile every group, note each kernel's specialisations, then make a capture
# and train a MoGaFace run (texture attention included) and note them again.
SCRIPT = """
import json, sys
from numba.core.registry import CPUDispatcher
from mogaface.core import precompile
from mogaface.core.correction import triplane_kernels
from mogaface.core.data import mesh_raster
from mogaface.core.data.generator import CaptureSettings, make_capture
from mogaface.core.splat import projection, raster, tiles
from mogaface.core.train import config as C, ssim_kernels
from mogaface.core.train.trainer import Trainer

def specialisations():
    return {f"{m.__name__.rsplit('.', 1)[1]}.{name}": sorted(map(str, kernel.signatures))
            for m in (projection, raster, tiles, mesh_raster, ssim_kernels, triplane_kernels)
            for name, kernel in vars(m).items() if isinstance(kernel, CPUDispatcher)}

precompile.compile_kernels(jobs=1)
before = specialisations()
root, run = sys.argv[1], sys.argv[2]
make_capture(root, CaptureSettings(views=3, timesteps=16, size=32, supersample=2), progress=False)
Trainer(root, run, C.resolve(preset="mogaface-demo", overrides={
    "train": {"steps": 2, "threads": 1, "log_every": 1}, "eval": {"at_end": False, "lpips": False}})).run()
print(json.dumps({"before": before, "after": specialisations()}))
"""


def test_a_capture_and_a_training_run_use_no_kernel_the_warm_up_left_out(tmp_path):
    result = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "capture"), str(tmp_path / "run")],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    seen = json.loads(result.stdout.strip().splitlines()[-1])
    before, after = seen["before"], seen["after"]
    # the warm-up reached the kernels of each group (and the run used them)
    for kernel in ("projection.project_backward", "raster.backward", "raster.reduce_slots", "tiles.pixel_bounds",
                   "mesh_raster.clip_near", "mesh_raster.shade", "ssim_kernels.backward", "triplane_kernels.backward"):
        assert before[kernel] and after[kernel] == before[kernel], kernel
    added = {name: sorted(set(after[name]) - set(before[name])) for name in after if after[name] != before[name]}
    assert added == {}


def test_the_command_compiles_each_group_in_processes_of_its_own_and_refuses_no_jobs(capsys):
    from mogaface.core.cli import main
    from mogaface.core.precompile import GROUPS

    assert main(["compile-kernels", "--jobs", "2"]) == 0  # spawned processes: their cache is this one's
    report = json.loads(capsys.readouterr().out)
    assert set(report["seconds"]) == set(GROUPS) and report["jobs"] == 2
    assert all(seconds > 0 for seconds in report["seconds"].values())
    assert report["cache"] and report["cache"].endswith("mogaface")
    assert main(["compile-kernels", "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err

