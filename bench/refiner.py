"""The multi-view refiner against test-time fitting on the same unseen frames: seconds per frame
(the source's own time, not the render that scores it), their ratio, and what each buys in PSNR
over the tracked parameters, in one run so the ratio holds however loaded the machine is.

``python -m mogaface bench refiner --avatar RUN`` (a run folder with ``refiner.pt``, from
``train-refiner``) prints JSON with the load average. Frames: the self-reenactment protocol (the
unseen sequence, every scored view left out of the sources' inputs), 12 spread over it (4 with
``--quick``).
"""

from __future__ import annotations

import os

# tracked_aligned: runs that fine-tuned; refined_fit_10: 10 fitting steps from the refiner's one pass
# on the timesteps training did not fit (`refine-tracking --fit-steps 10`)
SOURCES = ("tracked", "tracked_aligned", "refined_1", "refined_3", "fit_10", "refined_fit_10")


def run(threads: int = 2, quick: bool = False, avatar: str | None = None) -> dict:
    import torch

    from mogaface.core.errors import InputError
    from mogaface.core.evaluate.benchmark import score_source, standard_sources
    from mogaface.core.evaluate.protocols import protocol_frames
    from mogaface.core.evaluate.run_folder import RunFolder
    from mogaface.core.mogaface.avatar import load_run_avatar
    from mogaface.core.refiner.files import REFINER_FILE

    torch.set_num_threads(threads)
    folder = RunFolder(avatar or "out/demo/run")
    if not (folder.root / REFINER_FILE).exists():
        raise InputError(folder.root / REFINER_FILE, None, "no refiner: run 'train-refiner RUN' first")
    capture = folder.open_capture()
    trained = load_run_avatar(folder.root)
    sources = standard_sources(folder, capture, trained, fit_steps=(10,))
    frames = protocol_frames(capture, "self_reenactment", 4 if quick else 12)
    load_before = os.getloadavg()
    scores = {name: score_source(trained, capture, sources[name], frames, folder.background, lpips=False)
              for name in SOURCES if name in sources}
    tracked = scores["tracked"]["psnr"]
    return {
        "run": str(folder.root), "frames": len(frames), "threads": threads,
        "seconds_per_frame": {name: round(s["source_s"], 4) for name, s in scores.items()},
        "psnr_db": {name: round(s["psnr"], 3) for name, s in scores.items()},
        "psnr_gain_over_tracked_db": {name: round(s["psnr"] - tracked, 3) for name, s in scores.items()},
        "fitting_time_over_refiner": {
            f"{passes}": round(scores["fit_10"]["source_s"] / max(scores[f"refined_{passes}"]["source_s"], 1e-9), 2)
            for passes in (1, 3)},
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
