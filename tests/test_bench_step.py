"""``bench step``'s stopwatch: exclusive time per stage over nested calls, and wrappers that find
every function of the step they time (a function moved elsewhere fails here, not in a long run)
and put the originals back."""

import time

from mogaface.bench.step import Stopwatch, _instrument
from mogaface.core.train import training_view


def test_nested_stages_count_their_own_time_only():
    watch = Stopwatch()
    start = time.perf_counter()
    with watch.stage("outer"):
        time.sleep(0.02)
        with watch.stage("inner"):
            time.sleep(0.03)
    total = time.perf_counter() - start
    assert 0.025 <= watch.totals["inner"] < total
    assert 0.015 <= watch.totals["outer"] < total - 0.025
    assert abs(sum(watch.totals.values()) - total) < 0.005  # the stages add up to the whole


def test_every_timed_function_is_found_wrapped_and_restored():
    before = training_view.image_loss
    watch = Stopwatch()
    undo = _instrument(watch)
    try:
        assert training_view.image_loss is not before
        import torch

        pred = torch.rand(16, 16, 3)
        training_view.image_loss(pred, pred.clone())
        assert watch.totals["loss: L1 and the rest"] > 0
    finally:
        for restore in reversed(undo):
            restore()
    assert training_view.image_loss is before
