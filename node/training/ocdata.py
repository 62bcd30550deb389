"""One OC's training dataset (``OCData``): the candidate channels' arrays of each training
segment, and its CV folds; built by ``node.training.train.oc_datasets``, read by the CV, the
calibration (``node.training.calibrate``) and the envelope (``node.training.envelope``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from node.training.plateau_fit import Visit


@dataclass
class OCData:
    """Everything one OC's CV needs, per training run: the candidate channels' arrays."""

    name: str
    target: str
    candidates: list[str]
    runs: list[int]  # run index of each segment
    y: list[np.ndarray]  # target from the history start to the segment end
    X: list[np.ndarray]  # candidates, same rows
    start: list[int]  # index of the OC's first sample in y / X
    at: list[int] = field(default_factory=list)  # index of the OC's first sample in its run
    switch: str = ""  # the schedule's switch channel
    curves: list[dict] = field(default_factory=list)  # curve candidates (CurveModel params)
    z: list[np.ndarray] = field(default_factory=list)  # the target's 1x vectors, y's rows (empty: no phase)
    proms: list[dict] = field(default_factory=list)  # parametric candidates (ParametricOCModel params)
    unranked: list[str] = field(default_factory=list)  # candidates only the parametric models take
    folds: dict[int, int] = field(default_factory=dict)  # run -> its CV fold (``run_folds``; empty: its own)
    # each row's visit for the plateau shift (node.training.plateau_fit; None: not known), and
    # whether the shift is on the 1x vector; None: no shift learned
    plateaus: list[Visit | None] = field(default_factory=list)
    plateau_vector: bool | None = None
    settle: bool = False  # learn the settle anchor (node.models.settle)

    def fold(self, run: int) -> int:
        """The CV fold of ``run``: the run itself (leave one run out) unless ``folds`` says otherwise."""
        return self.folds.get(run, run)

    def fold_ids(self) -> list[int]:
        return sorted({self.fold(r) for r in self.runs})

    def held_out(self, f: int) -> list[int]:
        """The segments (rows) fold ``f`` holds out."""
        return [i for i, r in enumerate(self.runs) if self.fold(r) == f]

    def fitted_on(self, f: int) -> list[int]:
        """The segments (rows) fold ``f`` fits on: every other fold's."""
        return [i for i, r in enumerate(self.runs) if self.fold(r) != f]
