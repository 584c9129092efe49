"""The multi-view refiner against test-time fitting on the same unseen frames: seconds per frame
(the source's own time, not the render that scores it), their ratio, and what each buys in PSNR
over the tracked parameters, in one run so the ratio holds however loaded the machine is.

``python -m mogaface bench refiner --avatar RUN`` (a run folder with ``refiner.pt``, from
``train-refiner``) prints JSON with the load average. Frames: the self-reenactment protocol (the
unseen sequence, every scored view left out of the sources' inputs), 12 spread over it (4 with
``--quick``). ``--fit-steps 10,30,100`` times fitting at each length, for its curve of PSNR against
time: ten steps are not where fitting stops gaining.
"""

from __future__ import annotations

import os

# tracked_aligned: runs that fine-tuned; refined_fit_N: N fitting steps (the first of fit_steps) from
# the refiner's one pass on the timesteps training did not fit (`refine-tracking --fit-steps N`)
PASSES = (1, 3)


def run(threads: int = 2, quick: bool = False, avatar: str | None = None,
        fit_steps: tuple[int, ...] = (10,)) -> dict:
    import torch

    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.benchmark import score_source, standard_sources
    from mogaface.core.evaluate.protocols import protocol_frames
    from mogaface.core.run.folder import RunFolder
    from mogaface.core.refiner.files import REFINER_FILE

    torch.set_num_threads(threads)
    folder = RunFolder(avatar or "out/demo/run")
    if not (folder.root / REFINER_FILE).exists():
        raise InputError(folder.root / REFINER_FILE, None, "no refiner: run 'train-refiner RUN' first")
    capture = folder.open_capture()
    trained = folder.load_avatar()
    sources = standard_sources(folder, capture, trained, fit_steps=fit_steps, refiner_passes=PASSES)
    names = ["tracked", "tracked_aligned", *(f"refined_{k}" for k in PASSES), *(f"fit_{n}" for n in fit_steps),
             f"refined_fit_{fit_steps[0]}"]
    frames = protocol_frames(capture, "self_reenactment", 4 if quick else 12)
    load_before = os.getloadavg()
    scores = {name: score_source(trained, capture, sources[name], frames, folder.background, lpips=False)
              for name in names if name in sources}
    tracked = scores["tracked"]["psnr"]
    return {
        "run": str(folder.root), "frames": len(frames), "threads": threads,
        "seconds_per_frame": {name: round(s["source_s"], 4) for name, s in scores.items()},
        "psnr_db": {name: round(s["psnr"], 3) for name, s in scores.items()},
        "psnr_gain_over_tracked_db": {name: round(s["psnr"] - tracked, 3) for name, s in scores.items()},
        "fitting_time_over_refiner": {
            f"fit_{steps}/refined_{passes}": round(
                scores[f"fit_{steps}"]["source_s"] / max(scores[f"refined_{passes}"]["source_s"], 1e-9), 2)
            for steps in fit_steps for passes in PASSES},
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
