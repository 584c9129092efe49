"""The run folder: where a training run keeps its settings, progress, checkpoints and results.

::

    RUN/config.toml               the resolved settings (every key)
    RUN/head.pkl                  copy of the capture's head model (beside avatar.pt)
    RUN/run.json                  capture path, splits, background, extent, final step, wall time
    RUN/events.jsonl              progress events, one JSON object a line
    RUN/checkpoints/step_NNNNNN.pt, RUN/checkpoints/latest
    RUN/avatar.pt                 the trained avatar (Avatar.save)
    RUN/flame_param/TTTTT.npz     FLAME parameters used for each training timestep (VHAP form)
    RUN/metrics_train_end.json    quick val-split metrics after training
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

RUN_FORMAT = "mogaface-run"
RUN_VERSION = 1


@dataclasses.dataclass(frozen=True)
class RunFolder:
    root: pathlib.Path

    @classmethod
    def at(cls, path: str | os.PathLike) -> "RunFolder":
        return cls(pathlib.Path(path).resolve())

    @property
    def config(self) -> pathlib.Path:
        return self.root / "config.toml"

    @property
    def run_json(self) -> pathlib.Path:
        return self.root / "run.json"

    @property
    def events(self) -> pathlib.Path:
        return self.root / "events.jsonl"

    @property
    def checkpoints(self) -> pathlib.Path:
        return self.root / "checkpoints"

    @property
    def avatar(self) -> pathlib.Path:
        return self.root / "avatar.pt"

    @property
    def flame_params(self) -> pathlib.Path:
        return self.root / "flame_param"

    @property
    def metrics(self) -> pathlib.Path:
        return self.root / "metrics_train_end.json"

    def head(self, suffix: str = ".pkl") -> pathlib.Path:
        return self.root / f"head{suffix}"
