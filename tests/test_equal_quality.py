"""The refiner's time against fitting at equal quality: the fitting length that reaches a PSNR,
interpolated in log-steps over the measured lengths, and fitting's time at that length."""

import math

import pytest

from mogaface.core.evaluate.benchmark import matching_fit_length, seconds_at_length

CURVE = {10: 30.0, 30: 31.0, 100: 31.5}  # PSNR of fitting at three lengths


def test_a_psnr_between_two_lengths_is_interpolated_in_log_steps():
    match = matching_fit_length(CURVE, 30.5)
    assert match["status"] == "interpolated"
    assert match["steps"] == pytest.approx(math.sqrt(10 * 30))  # half-way in log-steps: the geometric mean
    assert matching_fit_length(CURVE, 31.25)["steps"] == pytest.approx(math.sqrt(30 * 100))
    assert matching_fit_length(CURVE, 31.0)["steps"] == pytest.approx(30)
    assert matching_fit_length({30: 31.0, 10: 30.0}, 30.5)["steps"] == pytest.approx(math.sqrt(300))  # any order


def test_a_refiner_better_than_the_longest_fit_is_not_reached():
    assert matching_fit_length(CURVE, 31.6) == {"steps": None, "status": "not reached"}


def test_a_refiner_worse_than_the_shortest_fit_is_reached_by_it():
    assert matching_fit_length(CURVE, 29.0) == {"steps": 10, "status": "reached by the shortest"}


def test_the_first_crossing_counts_on_a_curve_that_dips():
    match = matching_fit_length({10: 30.0, 30: 31.0, 100: 30.8}, 30.9)
    assert match["status"] == "interpolated" and 10 < match["steps"] < 30


def test_fitting_lengths_must_be_positive():
    with pytest.raises(ValueError):
        matching_fit_length({0: 29.0, 10: 30.0}, 29.5)
    with pytest.raises(ValueError):
        matching_fit_length({}, 29.5)


def test_fitting_time_at_a_length_is_linear_in_steps():
    seconds = {10: 1.0, 30: 2.8, 100: 9.0}
    assert seconds_at_length(seconds, 20) == pytest.approx(1.9)
    assert seconds_at_length(seconds, 30) == pytest.approx(2.8)
    assert seconds_at_length(seconds, 65) == pytest.approx(2.8 + 35 * 6.2 / 70)
    assert seconds_at_length({10: 1.0}, 25) == pytest.approx(2.5)  # one length: proportional
