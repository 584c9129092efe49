"""Every numeric setting has a range; values outside it are refused naming the key; the table in
docs/safety.md lists them all."""

import pathlib

import pytest

from mogaface.core.errors import InputError
from mogaface.core.train import config as C
from mogaface.core.train.config_ranges import RANGES, numeric_settings

DOC = pathlib.Path(__file__).resolve().parents[2] / "docs" / "safety.md"


def test_every_numeric_setting_has_a_range_and_defaults_lie_inside():
    keys = [k for k, _ in numeric_settings(C.TrainConfig())]
    assert sorted(keys) == sorted(RANGES)
    for key, value in numeric_settings(C.TrainConfig()):
        low, high = RANGES[key]
        assert low <= value <= high, key
    for preset in C.PRESETS:
        C.resolve(preset)


@pytest.mark.parametrize("key", sorted(RANGES))
def test_values_outside_the_range_are_refused(key):
    section, name = key.split(".")
    low, high = RANGES[key]
    kind = type(getattr(getattr(C.TrainConfig(), section), name))
    outside = (low - 1, high * 10) if kind is int else (low - abs(low) - 1.0, high * 10 + 1.0)
    for value in outside:
        value = kind(value) if kind is int else float(value)
        with pytest.raises(InputError, match=key.replace(".", r"\.")):
            C.resolve(overrides={section: {name: value}})


def test_docs_list_every_range():
    text = DOC.read_text()
    for key, (low, high) in RANGES.items():
        assert f"| `{key}` | {low:g} | {high:g} |" in text, key
