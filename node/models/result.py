"""What training learned for one OC: its model, inputs, scores and residual calibration.

Both are frozen: training builds them complete, a bundle stores and loads them.

>>> c = Calibration(sigma=0.2, threshold=4.0, peaks=[3.1, 2.7])
>>> c.persist, round(c.ewma_alpha, 4), c.peaks
(40, 0.0247, (3.1, 2.7))
"""

from __future__ import annotations

from dataclasses import dataclass, field

from node.contract import FS
from node.models.average import member_label
from node.models.envelope import Envelope
from node.models.ocmodel import OCModel
from node.models.plateau import PlateauShift
from node.models.settle import SettleAnchor

EWMA_SPAN_S = 2.0  # smoothing of the standardized residual, s
PERSIST_S = 1.0  # an alarm needs the smoothed score beyond threshold this long, s
EWMA_ALPHA = 2.0 / (EWMA_SPAN_S * FS + 1.0)
PERSIST = int(PERSIST_S * FS)


@dataclass(frozen=True)
class Calibration:
    """Residual statistics of one OC: sigma (target units) and the alarm rule.

    threshold is on the smoothed standardized score (sigma units); ewma_alpha its
    smoothing per sample; persist the samples it must stay beyond. peaks are the CV
    segments' peak |scores| it was calibrated from (see ``node.runtime.alarms``);
    segments the CV segments as (run, start sample, mean z^2).
    """

    sigma: float
    threshold: float
    ewma_alpha: float = EWMA_ALPHA
    persist: int = PERSIST
    peaks: tuple[float, ...] = ()
    segments: tuple[tuple[int, int, float], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "peaks", tuple(self.peaks))
        object.__setattr__(self, "segments", tuple(self.segments))


@dataclass(frozen=True, eq=False)
class OCResult:
    """What training learned and measured for one OC (``model`` None: not trained, see ``note``)."""

    name: str
    model: OCModel | None
    inputs: list[str]
    params: dict
    n_runs: int
    train_eps: float
    cv_eps: float
    calibration: Calibration | None
    ranking: list[tuple[str, float]] = field(default_factory=list)
    cv_scores: list[tuple[dict, float]] = field(default_factory=list)
    note: str = ""
    envelope: Envelope | None = None  # the region its training runs covered (node.models.envelope)
    outside_cv: tuple[float, int] | None = None  # CV samples beyond their fold's envelope: sum z^2, count
    plateau: PlateauShift | None = None  # what the run's earlier plateaus add (node.models.plateau)
    settle: SettleAnchor | None = None  # the re-anchor on the visit's own level (node.models.settle)

    @property
    def kind(self) -> str:
        """The model's kind for tables: its method, a curve with its variant ("curve:anchored"),
        "+plateau" where a plateau shift moves it, "+settle" where a settle anchor does; "-"
        without a model."""
        if self.model is None:
            return "-"
        shift = "+plateau" if self.plateau is not None else ""
        shift += "+settle" if self.settle is not None else ""
        if "members" in self.params:  # an average: "average:vector+influence+wdmd"
            return f"{self.model.method.value}:{member_label(self.params)}{shift}"
        variant = self.params.get("variant")
        return (f"{self.model.method.value}:{variant}" if variant else self.model.method.value) + shift
