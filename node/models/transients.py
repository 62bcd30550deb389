"""The fleet's transients: per kind of transition and resonance, the spread of the critical speed
and the amplification factor over the training runs, and the rule that flags a shift beyond it.

A bundle keeps them in its manifest (``"transients"``, JSON, versioned ``TRANSIENTS_VERSION``);
a bundle without them (trained before) loads with none: the node then publishes its transient
messages with ``expected_speed`` and ``shift`` null and flag ``no-model``, never an alarm.

The kind of a transition (``transition_kind``) is its direction and where it starts and ends: an
OC whose plateau speed lies within ``KIND_NEAR`` of the speed, else a band of ``BAND_PCT`` % of
the schedule's top plateau speed (idle, off). The criticals found in a transition match the
fleet resonances of the same kind by mode order under one common ratio (``FleetTransients.match``),
each within ``match_pct`` % of its resonance times that ratio. Its shift, (speed -
mean) / mean in %, is an alarm beyond ``limit``: ``k_sigma`` times the fleet's standard deviation
in %, widened by sqrt(1 + 1 / n) for a mean of n transitions, and never below ``floor_pct``
(few runs underestimate a spread; the floor also covers what the fleet's runs never showed,
such as a metal temperature they never reached); a resonance seen in fewer than ``MIN_SEEN``
transitions of its kind, or in less than half of them, raises nothing.

>>> s = FleetStat.of([9600.0, 9650.0, 9700.0])
>>> round(s.mean), round(s.std, 1), s.count
(9650, 50.0, 3)
>>> af = FleetStat.of([15.0, 15.0, 15.0])
>>> fleet = FleetTransients(TransientSettings(), {"up R1->R2": Kind(4, (Resonance(s, s, af),))})
>>> res, shift, limit = fleet.compare("up R1->R2", 9170.0)
>>> round(shift, 2), round(limit, 2), abs(shift) > limit
(-4.97, 2.5, True)
>>> FleetTransients.from_manifest(fleet.manifest()) == fleet
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

TRANSIENTS_VERSION = 1
K_SIGMA = 4.0  # an alarm beyond this many fleet sigmas (see docs/transients.md: the calibration)
FLOOR_PCT = 2.5  # ... and never within this many % of the fleet's mean
MATCH_PCT = 8.0  # a critical matches a resonance within this many % of its mean (times the common ratio)
MAX_COMMON_PCT = 25.0  # the common ratio of a transition's criticals to the fleet's: at most this far from 1
MATCH_RESOLUTION = 1e-9  # the matching's figures are compared rounded to this
AF_FLOOR_PCT = 40.0  # an AF's rise over the fleet's mean is an alarm beyond k sigma and never within this
JOIN_PCT = 3.0  # training: criticals of a kind within this many % of a group's mean are one resonance
MIN_SEEN = 2  # a resonance seen in fewer transitions of its kind raises nothing
BAND_PCT = 5.0  # a speed that is no OC's plateau is labelled by a band this wide, % of the top plateau
KIND_NEAR = 0.04  # a speed within this fraction of an OC's plateau speed is that OC
MAX_KINDS = 1000  # kinds a bundle may hold (bounded input)
MAX_RESONANCES = 100  # resonances per kind


@dataclass(frozen=True)
class FleetStat:
    """Mean, (sample) standard deviation and count of one quantity over the fleet's transitions."""

    mean: float
    std: float
    count: int

    @classmethod
    def of(cls, values: Sequence[float]) -> FleetStat:
        n = len(values)
        m = math.fsum(values) / n
        sd = math.sqrt(math.fsum((v - m) ** 2 for v in values) / (n - 1)) if n > 1 else 0.0
        return cls(m, sd, n)

    def to_dict(self) -> dict[str, float]:
        return {"mean": self.mean, "std": self.std, "count": self.count}

    @classmethod
    def from_dict(cls, d: object) -> FleetStat:
        if not isinstance(d, dict):
            raise ValueError("a fleet statistic must be an object")
        mean, std, count = d.get("mean"), d.get("std"), d.get("count")
        for name, v in (("mean", mean), ("std", std)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"fleet statistic {name} must be a finite number, got {v!r}")
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"fleet statistic count must be a positive integer, got {count!r}")
        if std < 0:  # type: ignore[operator]
            raise ValueError(f"fleet statistic std must be >= 0, got {std!r}")
        return cls(float(mean), float(std), count)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Resonance:
    """One resonance of a kind of transition: its critical speed in rpm of the switch channel
    (``speed``) and of the shaft analysed (``shaft``: the one compared, the physical critical;
    the switch speed at that moment also varies with how the shafts lag each other through the
    transition), and its AF."""

    speed: FleetStat
    shaft: FleetStat
    af: FleetStat


@dataclass(frozen=True)
class Kind:
    """One kind of transition: how many the training runs made, and the resonances they crossed."""

    transitions: int
    resonances: tuple[Resonance, ...]


TRACKER_S_MAX = 60.0  # the longest order-tracker lag that can be undone, s
TRACKER_FROM = ("estimated", "given", "none")  # how a bundle's tracker lag was found


@dataclass(frozen=True)
class TransientSettings:
    """How the transitions are analysed and compared (stored with the fleet's figures).

    speed: the channel the 1x vector is analysed on (the target's own shaft; None: the
    schedule's switch channel); phase: the target's phase channel is used; tracker_s: the order
    tracker's lag undone (s; 0: none, alike in training and monitoring); tracker_from: how it was
    found (``TRACKER_FROM``: "estimated" from the training runs' resonance crossings,
    ``node.runtime.tracker_lag``; "given" by ``train --tracker-s``; "none": neither);
    tracker_spread: the estimate's spread over the crossings (s), tracker_crossings: how many
    crossings it rests on; min_amplitude: criticals
    below it (the target's unit) are left out; k_sigma, floor_pct, match_pct: the alarm rule
    (module docstring).
    """

    speed: str | None = None
    phase: bool = False
    tracker_s: float = 0.0
    min_amplitude: float = 0.2
    k_sigma: float = K_SIGMA
    floor_pct: float = FLOOR_PCT
    match_pct: float = MATCH_PCT
    tracker_from: str = "none"
    tracker_spread: float = 0.0
    tracker_crossings: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"speed": self.speed, "phase": self.phase, "tracker_s": self.tracker_s,
                "min_amplitude": self.min_amplitude, "k_sigma": self.k_sigma,
                "floor_pct": self.floor_pct, "match_pct": self.match_pct,
                "tracker_from": self.tracker_from, "tracker_spread": self.tracker_spread,
                "tracker_crossings": self.tracker_crossings}

    @classmethod
    def from_dict(cls, d: object) -> TransientSettings:
        if not isinstance(d, dict):
            raise ValueError("transients.settings must be an object")
        unknown = sorted(set(d) - set(cls().to_dict()))
        if unknown:
            raise ValueError(f"unknown transients setting(s): {', '.join(unknown)}")
        speed, phase = d.get("speed"), d.get("phase", False)
        if speed is not None and not isinstance(speed, str):
            raise ValueError(f"transients.settings.speed must be a channel name or null, got {speed!r}")
        if not isinstance(phase, bool):
            raise ValueError(f"transients.settings.phase must be true or false, got {phase!r}")
        nums = {}
        for key, lo, hi in (("tracker_s", 0.0, TRACKER_S_MAX), ("min_amplitude", 0.0, 1e6),
                            ("k_sigma", 0.0, 1e3), ("floor_pct", 0.0, 100.0), ("match_pct", 0.0, 100.0),
                            ("tracker_spread", 0.0, TRACKER_S_MAX)):
            v = d.get(key, getattr(cls(), key))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ValueError(f"transients.settings.{key} must be a number in [{lo:g}, {hi:g}], got {v!r}")
            nums[key] = float(v)
        how = d.get("tracker_from", "given" if nums["tracker_s"] > 0 else "none")  # (older bundles)
        crossings = d.get("tracker_crossings", 0)
        if how not in TRACKER_FROM:
            raise ValueError(f"transients.settings.tracker_from must be one of {', '.join(TRACKER_FROM)}, "
                             f"got {how!r}")
        if isinstance(crossings, bool) or not isinstance(crossings, int) or not 0 <= crossings <= 10**6:
            raise ValueError(f"transients.settings.tracker_crossings must be a count, got {crossings!r}")
        return cls(speed, phase, **nums, tracker_from=how, tracker_crossings=crossings)


@dataclass(frozen=True)
class FleetTransients:
    """The fleet's transients of one target: settings and, per kind (``transition_kind``), the
    resonances in ascending mean speed."""

    settings: TransientSettings
    kinds: dict[str, Kind] = field(default_factory=dict)

    def limit(self, res: Resonance, transitions: int) -> float | None:
        """The |shift| (%) beyond which a critical of ``res`` is an alarm; None: it raises none
        (seen too seldom among the ``transitions`` of its kind)."""
        n = res.shaft.count
        if n < MIN_SEEN or 2 * n < transitions:
            return None
        spread = 100.0 * res.shaft.std / res.shaft.mean * math.sqrt(1.0 + 1.0 / n)
        return max(self.settings.k_sigma * spread, self.settings.floor_pct)

    def match(self, kind: str, speeds: Sequence[float]) -> list[Resonance | None]:
        """The fleet resonance each critical of one transition matches (``speeds`` rpm of the
        shaft analysed, ascending; None: none), by mode order under one common ratio.

        A stiffness change moves every critical by about the same ratio (a 20 % loss about
        10.6 %), beyond ``match_pct`` of its own resonance and maybe nearer another one's. So
        the criticals are matched in ascending order, each resonance at most once, under the
        ratio g (found speed over fleet mean) that makes the most of them agree: each within
        ``match_pct`` of g times its resonance, g within ``MAX_COMMON_PCT`` of 1. A ratio beyond
        ``match_pct`` needs two criticals or more to agree on it; ties go to the ratio nearer 1
        (modes spaced by about the ratio itself are ambiguous: the nearer ratio wins). Then a
        critical still new, where the transition missed a resonance it crosses as a rule (seen
        in most transitions of its kind: ``limit`` not None) within ``MAX_COMMON_PCT`` and
        between the same matched neighbours, is that resonance shifted (most ramps between
        plateaus cross one mode: no common ratio to agree on). The figures are compared rounded
        (``MATCH_RESOLUTION``), so rounding cannot flip a choice.

        >>> s = lambda x: FleetStat(x, 10.0, 4)
        >>> k = Kind(4, (Resonance(s(4500.0), s(4500.0), s(6.0)), Resonance(s(8200.0), s(8200.0), s(15.0))))
        >>> fleet = FleetTransients(TransientSettings(), {"down A->B": k})
        >>> [r.shaft.mean if r else None for r in fleet.match("down A->B", [4010.0, 7320.0])]  # 10.8 % low
        [4500.0, 8200.0]
        >>> [r.shaft.mean if r else None for r in fleet.match("down A->B", [7320.0])]  # 8,200 missed
        [8200.0]
        >>> [r.shaft.mean if r else None for r in fleet.match("down A->B", [4480.0, 6100.0])]  # new
        [4500.0, None]
        >>> [r.shaft.mean if r else None for r in fleet.match("down A->B", [4480.0, 8230.0])]
        [4500.0, 8200.0]
        """
        k = self.kinds.get(kind)
        n = len(speeds)
        if k is None or not k.resonances or not n:
            return [None] * n
        res = k.resonances
        tol = math.log1p(self.settings.match_pct / 100.0)
        wide = math.log1p(MAX_COMMON_PCT / 100.0)
        logs = [[math.log(c / r.shaft.mean) if c > 0 else math.inf for r in res] for c in speeds]
        ratios = sorted({0.0, *(x for row in logs for x in row if abs(x) <= wide)}, key=abs)
        best: tuple[float, float, list[int | None]] | None = None
        for g in ratios:
            pairs = _ordered_pairs(logs, g, tol)
            if len(pairs) < 2 and abs(g) > tol:
                continue
            fit = math.fsum(abs(logs[i][j] - g) for i, j in pairs)
            key = (_rounded(-len(pairs) + fit / (2.0 * tol * (n + 1))), _rounded(abs(g)))
            if best is None or key < best[:2]:
                out: list[int | None] = [None] * n
                for i, j in pairs:
                    out[i] = j
                best = (*key, out)
        assert best is not None  # g = 0 is always tried
        out = best[2]
        # a critical left new where the transition missed a resonance it crosses as a rule (seen
        # in most transitions of its kind), in between the same matched neighbours: that one shifted
        for i in range(n):
            if out[i] is not None:
                continue
            lo = max((j for j in out[:i] if j is not None), default=-1)
            hi = min((j for j in out[i + 1:] if j is not None), default=len(res))
            free = [j for j in range(lo + 1, hi) if j not in out and abs(logs[i][j]) <= wide
                    and self.limit(res[j], k.transitions) is not None]
            if free:
                out[i] = min(free, key=lambda j: (_rounded(abs(logs[i][j])), j))
        return [None if j is None else res[j] for j in out]

    def shifted(self, res: Resonance, speed: float, transitions: int) -> tuple[float, float | None]:
        """A critical at ``speed`` (rpm of the shaft analysed) matched to ``res`` in a kind of
        ``transitions``: its shift in % and the limit (``limit``)."""
        return 100.0 * (speed - res.shaft.mean) / res.shaft.mean, self.limit(res, transitions)

    def af_rise(self, res: Resonance, af: float, transitions: int) -> tuple[float, float | None]:
        """An AF ``af`` of a critical matched to ``res``: its rise over the fleet's mean AF in %
        and the rise beyond which it is an alarm (lost damping: ``k_sigma`` times the fleet's
        spread, never below ``AF_FLOOR_PCT``; None: the resonance raises none)."""
        if self.limit(res, transitions) is None or not res.af.mean > 0 or not math.isfinite(af):
            return math.nan, None
        n = res.af.count
        spread = 100.0 * res.af.std / res.af.mean * math.sqrt(1.0 + 1.0 / n)
        return 100.0 * (af - res.af.mean) / res.af.mean, max(self.settings.k_sigma * spread, AF_FLOOR_PCT)

    def compare(self, kind: str, speed: float) -> tuple[Resonance | None, float | None, float | None]:
        """One critical at ``speed`` (rpm of the shaft analysed) alone in a transition of ``kind``:
        the fleet resonance it matches (``match``; None: none), its shift in % and the limit."""
        res = self.match(kind, [speed])[0]
        if res is None:
            return None, None, None
        shift, limit = self.shifted(res, speed, self.kinds[kind].transitions)
        return res, shift, limit

    def manifest(self) -> dict[str, Any]:
        """The bundle manifest's ``transients`` object."""
        return {"version": TRANSIENTS_VERSION, "settings": self.settings.to_dict(),
                "kinds": {name: {"transitions": k.transitions,
                                 "resonances": [{"speed": r.speed.to_dict(), "shaft": r.shaft.to_dict(),
                                                 "af": r.af.to_dict()} for r in k.resonances]}
                          for name, k in self.kinds.items()}}

    @classmethod
    def from_manifest(cls, d: object) -> FleetTransients:
        """From a manifest's ``transients`` object (ValueError for a malformed or newer one)."""
        if not isinstance(d, dict):
            raise ValueError("transients must be an object")
        if d.get("version") != TRANSIENTS_VERSION:
            raise ValueError(f"transients version {d.get('version')!r} is not supported "
                             f"(this ordervib reads {TRANSIENTS_VERSION})")
        settings = TransientSettings.from_dict(d.get("settings", {}))
        kinds = d.get("kinds", {})
        if not isinstance(kinds, dict) or len(kinds) > MAX_KINDS:
            raise ValueError(f"transients.kinds must be an object of at most {MAX_KINDS} kinds")
        out = {}
        for name, k in kinds.items():
            if not isinstance(k, dict) or not isinstance(k.get("resonances"), list) \
                    or len(k["resonances"]) > MAX_RESONANCES:
                raise ValueError(f"transients.kinds[{name!r}] must hold at most {MAX_RESONANCES} resonances")
            n = k.get("transitions")
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise ValueError(f"transients.kinds[{name!r}].transitions must be a positive integer")
            res = []
            for r in k["resonances"]:
                if not isinstance(r, dict):
                    raise ValueError(f"transients.kinds[{name!r}]: a resonance must be an object")
                speed, shaft = FleetStat.from_dict(r.get("speed")), FleetStat.from_dict(r.get("shaft"))
                if speed.mean <= 0 or shaft.mean <= 0:
                    raise ValueError(f"transients.kinds[{name!r}]: a critical speed must be positive")
                res.append(Resonance(speed, shaft, FleetStat.from_dict(r.get("af"))))
            out[str(name)] = Kind(n, tuple(sorted(res, key=lambda x: x.shaft.mean)))
        return cls(settings, out)


def _ordered_pairs(logs: list[list[float]], g: float, tol: float) -> list[tuple[int, int]]:
    """The most (critical i, resonance j) pairs, both ascending, each |logs[i][j] - g| <= tol,
    fewest misfit among equals (a longest common subsequence by dynamic programming)."""
    n, m = len(logs), len(logs[0]) if logs else 0
    # best[i][j]: (pairs, -misfit) over criticals i.. and resonances j..
    best = [[(0, 0.0)] * (m + 1) for _ in range(n + 1)]
    for i in range(n - 1, -1, -1):
        for j in range(m - 1, -1, -1):
            cands = [best[i + 1][j], best[i][j + 1]]
            d = abs(logs[i][j] - g)
            if d <= tol:
                p, f = best[i + 1][j + 1]
                cands.append((p + 1, f - d))
            best[i][j] = max(cands)
    out, i, j = [], 0, 0
    while i < n and j < m:
        d = abs(logs[i][j] - g)
        if d <= tol and best[i][j] == (best[i + 1][j + 1][0] + 1, best[i + 1][j + 1][1] - d):
            out.append((i, j))
            i, j = i + 1, j + 1
        elif best[i][j] == best[i + 1][j]:
            i += 1
        else:
            j += 1
    return out


def _rounded(x: float) -> float:
    return round(x / MATCH_RESOLUTION) * MATCH_RESOLUTION


def speed_label(speed: float, plateaus: Sequence[tuple[str, float]]) -> str:
    """An OC's name where ``speed`` lies within ``KIND_NEAR`` of its plateau (the nearest; the first
    of equal ones), else the band of ``BAND_PCT`` % of the top plateau it falls in.

    >>> p = [("OC1", 6500.0), ("OC2", 9800.0)]
    >>> speed_label(6420.0, p), speed_label(2900.0, p), speed_label(12.0, p)
    ('OC1', '30%', '0%')
    """
    top = max((s for _, s in plateaus), default=0.0)
    if plateaus:
        name, plateau = min(plateaus, key=lambda p: abs(speed - p[1]))
        if plateau > 0 and abs(speed / plateau - 1.0) <= KIND_NEAR:
            return name
    if not top > 0 or not math.isfinite(speed):
        return "?"
    return f"{BAND_PCT * round(100.0 * speed / top / BAND_PCT):g}%"


def transition_kind(direction: str, from_speed: float, to_speed: float,
                    plateaus: Sequence[tuple[str, float]]) -> str:
    """The kind of a transition: ``"<direction> <from>-><to>"`` (``speed_label`` each end).

    >>> transition_kind("up", 2950.0, 6480.0, [("OC1", 6500.0), ("OC2", 9800.0)])
    'up 30%->OC1'
    """
    return f"{direction} {speed_label(from_speed, plateaus)}->{speed_label(to_speed, plateaus)}"
