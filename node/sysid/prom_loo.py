"""Leave-one-sample-out validation of a parametric ROM's choices (chapter 6's pROM, checked on its
own data).

Each sample is held out in turn: the ROM is rebuilt from the other samples' models for every
candidate setting (how modes are matched, whether veering groups are blocks, how many pairs are
kept, the interpolation weights and coordinates), interpolated to the held-out sample's parameter
(an interior sample) or extrapolated to it (a sample at the edge of the range, which counts
``EDGE`` as much) and run from rest under that sample's inputs; its eps_td against that
sample's measured outputs (pooled over the sample's runs, capped at 1: no better than predicting
zero) is the candidate's score there. The nearest other sample's model, run the same way, is the
score to beat. A candidate's score is the weighted mean over the held-out samples.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from node.sysid.metrics import pooled_eps
from node.sysid.statespace import StateSpace

TIE = 0.02  # relative: candidates this close to the best score count as tied (the earlier wins)
# a candidate must score below MARGIN times the nearest other sample's model to be used: the folds
# rebuild each held-out sample from coarser samples than the final model has, and the nearest
# sample is farther from a held-out sample (a whole gap) than from a point between samples (at most
# half a gap), so a candidate that only just beats it on the folds is not shown to beat it there
MARGIN = 0.85
EDGE = 0.3  # weight of a fold that extrapolates to a sample at the edge (an interior one: 1)
SPECTRAL = 0.0  # weight of the log-spectral distance beside the capped eps_td in a fold's score
EXCITED = 1e-3  # a frequency counts when some input's spectrum there is above this x its peak
Data = list[tuple[np.ndarray, np.ndarray]]  # one sample's runs: (Y (K, p), U (K, m)) pairs


@dataclass(frozen=True)
class Candidate:
    """One setting of the choices validated: ``match``, ``block`` (veering groups: ``"joint"``,
    ``"interpolate"`` or ``"none"``, no groups), ``n_pairs`` kept, ``weights``, ``scheme``
    (the coordinates interpolated: ``"modal"``, ``"inverse"``, ``"direct"``)."""

    match: str
    block: str
    n_pairs: int
    weights: str
    scheme: str = "modal"

    def label(self) -> str:
        """A short name, e.g. ``continuation/joint/4 pairs/lagrange/modal``."""
        return f"{self.match}/{self.block}/{self.n_pairs} pairs/{self.weights}/{self.scheme}"


@dataclass(frozen=True)
class Validation:
    """What ``ParametricROM.validation_`` holds: how the settings were decided and the scores.

    ``rule``: ``"loo"`` (scored), else why nothing was scored (``"no data"``: built from models
    alone; ``"no interior sample"``; ``"off"``: ``validate="none"``). ``held_out`` (h,): the
    samples held out; ``weights`` (h,) their weights (1 interior, ``EDGE`` at the edge);
    ``candidates`` (c,); ``scores`` (c, h) eps_td (``score``) of each
    candidate on each held-out sample's data (inf: it could not be built); ``nearest`` (h,) that
    of the nearest other sample's model there; ``chosen``: the candidate the ROM uses (None: it
    falls back to the nearest sample's model, ``fallback``).
    """

    rule: str
    chosen: Candidate | None
    held_out: tuple[int, ...] = ()
    candidates: tuple[Candidate, ...] = ()
    scores: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    nearest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fallback: bool = False
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def _w(self) -> np.ndarray:
        w = self.weights if len(self.weights) == len(self.held_out) else np.ones(len(self.held_out))
        return w / w.sum()

    def mean_scores(self) -> np.ndarray:
        """(c,) each candidate's weighted mean score over the held-out samples."""
        return self.scores @ self._w() if self.scores.size else np.zeros(len(self.candidates))

    def nearest_score(self) -> float:
        """The nearest other sample's model's weighted mean score (inf: nothing held out)."""
        return float(self.nearest @ self._w()) if len(self.nearest) else float("inf")

    def ranking(self) -> list[int]:
        """Candidate indices, best first: by mean score, those within ``TIE`` (relative) of the
        best counted as tied with it and kept in candidate order (the defaults first)."""
        m = self.mean_scores()
        lo = float(np.min(m)) if len(m) else np.inf
        tied = [i for i in range(len(m)) if np.isfinite(lo) and m[i] <= lo * (1 + TIE)]
        return tied + [int(i) for i in np.argsort(m, kind="stable") if i not in tied]

    def best(self) -> tuple[Candidate, float] | None:
        """The best-ranked candidate and its mean score (None when nothing was scored)."""
        if not self.candidates or not self.held_out:
            return None
        i = self.ranking()[0]
        return self.candidates[i], float(self.mean_scores()[i])

    def summary(self) -> str:
        """One line: the rule, the chosen setting and its score beside the nearest sample's."""
        best = self.best()
        if best is None:
            return f"validation: {self.rule}; settings as given" + \
                (f" ({self.chosen.label()})" if self.chosen else "")
        near = self.nearest_score()
        held = ",".join(str(i) for i in self.held_out)
        if self.fallback:
            return (f"validation: loo on sample(s) {held}: no candidate beats {MARGIN:g} x the nearest "
                    f"sample's model (best {best[0].label()} eps_td {best[1]:.3g}, nearest {near:.3g}): "
                    f"the nearest sample's model")
        return (f"validation: loo on sample(s) {held}: {best[0].label()} eps_td {best[1]:.3g} "
                f"(nearest sample's {near:.3g}; {len(self.candidates)} candidates)")

    def table(self) -> list[tuple[str, float]]:
        """(label, mean score) of every candidate, best first, then the nearest sample's model."""
        m = self.mean_scores()
        rows = [(self.candidates[i].label(), float(m[i])) for i in self.ranking()]
        return rows + ([("nearest sample's model", self.nearest_score())] if self.held_out else [])


def interior(P: np.ndarray, scale: np.ndarray) -> list[int]:
    """Samples inside the range (one parameter) or the convex hull (several) of the others."""
    n, q = P.shape
    out = []
    for i in range(n):
        others = np.delete(P, i, axis=0) / scale
        x = P[i] / scale
        if np.any(np.all(np.isclose(others, x), axis=1)):
            continue  # a repeated parameter value: nothing to interpolate
        if q == 1:
            inside = bool(others.min() < x[0] < others.max())
        else:
            from scipy.spatial import Delaunay, QhullError
            try:
                inside = bool(Delaunay(others).find_simplex(x[None, :])[0] >= 0)
            except (QhullError, ValueError):
                inside = False
        if inside:
            out.append(i)
    return out


def nearest(P: np.ndarray, scale: np.ndarray, x: np.ndarray, among: Sequence[int]) -> int:
    """The sample of ``among`` nearest to x (q,) in range-scaled distance (the first on a tie)."""
    d = [float(np.linalg.norm((P[j] - x) / scale)) for j in among]
    return int(among[int(np.argmin(d))])


def score(model: StateSpace, data: Data) -> float:
    """eps_td of ``model``'s free runs from rest under each run's inputs, pooled over the runs,
    capped at 1: a prediction no better than zero tells nothing more by being worse (a lightly
    damped mode a little off in frequency drifts out of phase and scores up to 1.4, an
    absent one 1)."""
    try:
        with np.errstate(all="ignore"):
            eps = pooled_eps([(Y, model.simulate(U)) for Y, U in data])
    except (np.linalg.LinAlgError, ValueError):
        eps = float("inf")
    return min(eps, 1.0)


def validate(models: Sequence[StateSpace], P: np.ndarray, scale: np.ndarray, data: Sequence[Data],
             candidates: Sequence[Candidate], build: Callable[[Candidate, list[int]], Any],
             ) -> Validation:
    """Score every candidate by leave-one-sample-out, when some sample is interior.

    ``build(candidate, rest)`` returns a ROM built from the samples ``rest`` (indices), with
    ``model_for(x, candidate)`` (its model at parameter x for the candidate's weights and
    scheme), or raises ValueError / LinAlgError; candidates that differ only in ``weights`` or
    ``scheme`` share one build. Every sample is held out when some is interior (the others, at
    the edge, extrapolated to at ``EDGE`` weight). The chosen
    candidate is the lowest weighted mean score (the first within ``TIE`` of it); ``fallback``
    when it does not beat ``MARGIN`` times the nearest sample's model's.
    """
    inner = interior(P, scale)
    held = [i for i in range(len(P)) if i in inner or EDGE > 0] if inner else []
    w = np.array([1.0 if i in inner else EDGE for i in held])
    scores = np.full((len(candidates), len(held)), np.inf)
    near = np.full(len(held), np.inf)
    for h, i in enumerate(held):
        rest = [j for j in range(len(P)) if j != i]
        near[h] = score(models[nearest(P, scale, P[i], rest)], data[i])
        seen: dict[bytes, float] = {}
        built: dict[tuple[str, str, int], Any] = {}
        for c, cand in enumerate(candidates):
            key = (cand.match, cand.block, cand.n_pairs)
            if key not in built:
                try:
                    built[key] = build(cand, rest)
                except (ValueError, np.linalg.LinAlgError):
                    built[key] = None
            rom = built[key]
            if rom is None:
                continue
            try:
                with np.errstate(all="ignore"):
                    m = rom.model_for(P[i], cand)
            except (ValueError, np.linalg.LinAlgError):
                continue
            tag = b"".join(np.ascontiguousarray(a).tobytes() for a in (m.A, m.B, m.C, m.D))
            if tag not in seen:  # the same model from another setting: scored once
                seen[tag] = score(m, data[i])
            scores[c, h] = seen[tag]
    val = Validation("loo", None, tuple(held), tuple(candidates), scores, near, weights=w)
    best = val.best()
    if best is None:
        return val
    ok = bool(np.isfinite(best[1]) and best[1] < MARGIN * val.nearest_score())
    return replace(val, chosen=best[0] if ok else None, fallback=not ok)
