"""The pass-off schedule (docs/contract.md section 4): which OCs, in which order, at which speed,
and the acceptance limits of the tracked orders (``[[limit]]``, ``Limit``)."""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass

from node.contract.errors import OrdervibError
from node.contract.keys import RESERVED_NAMES, is_name

# The segment after the last plateau, from its departure (fuel off) to standstill (section 4):
# monitored like an OC, under this name, which no OC of a schedule may take.
RUNDOWN = "rundown"


def start_name(first: str) -> str:
    """The name of the start's model, of a schedule whose first OC is ``first``."""
    return f"{first}:start"


@dataclass(frozen=True)
class OperatingCondition:
    name: str
    speed: float  # plateau speed, in the unit of the switch channel


MAX_LIMITS = 1000  # [[limit]] tables a schedule holds at most
LIMIT_KEYS = frozenset({"target", "max", "from_speed", "to_speed", "oc"})


@dataclass(frozen=True)
class Limit:
    """An acceptance limit: ``target`` (a modelled channel) must stay at or below ``max`` (its
    unit) within a speed band of the switch channel (``from_speed`` to ``to_speed``, rpm, ends
    included; one end alone is open on the other side), or in one segment (``oc``: an OC, in
    its transition and its plateau, or ``RUNDOWN``), or everywhere (neither given).

    >>> lim = Limit("yB", 12.0, from_speed=7000.0, to_speed=9900.0)
    >>> lim.applies(8000.0, "OC7"), lim.applies(6999.0, "OC7"), Limit("yB", 9.0, oc="OC7").applies(0.0, "OC7")
    (True, False, True)
    """

    target: str
    max: float
    from_speed: float | None = None
    to_speed: float | None = None
    oc: str | None = None

    def applies(self, speed: float, oc: str | None) -> bool:
        """Whether the limit is in force at a sample of switch speed ``speed`` (NaN: unknown, no
        band applies) in segment ``oc`` (None: the engine off)."""
        if self.oc is not None:
            return oc == self.oc
        lo, hi = self.from_speed, self.to_speed
        if lo is None and hi is None:
            return True
        return (lo is None or speed >= lo) and (hi is None or speed <= hi)

    def to_dict(self) -> dict:
        d: dict = {"target": self.target, "max": self.max}
        for key in ("from_speed", "to_speed", "oc"):
            if getattr(self, key) is not None:
                d[key] = getattr(self, key)
        return d

    def where(self) -> str:
        """Where it applies, in words (``oc OC7``, ``7000-9900``, ``everywhere``)."""
        if self.oc is not None:
            return f"oc {self.oc}"
        if self.from_speed is None and self.to_speed is None:
            return "everywhere"
        return f"{_speed(self.from_speed)}-{_speed(self.to_speed)}"


def limit_in_force(limits: Sequence[Limit], speed: float, oc: str | None) -> float | None:
    """The limit in force at a sample (the one rule of the node, replay and training): the smallest
    ``max`` of ``limits`` that apply at switch speed ``speed`` in segment ``oc``; None: none does.

    >>> band, seg = Limit("yB", 12.0, from_speed=7000.0, to_speed=9900.0), Limit("yB", 9.0, oc="OC7")
    >>> limit_in_force((band, seg), 8000.0, "OC7"), limit_in_force((band, seg), 8000.0, "OC6")
    (9.0, 12.0)
    >>> limit_in_force((band, seg), float("nan"), "OC6") is None
    True
    """
    out = None
    for lim in limits:
        if (out is None or lim.max < out) and lim.applies(speed, oc):
            out = lim.max
    return out


def _speed(x: float | None) -> str:
    return "" if x is None else f"{x:g}"


def _limit(d: object, k: int, source: str) -> Limit:
    """The k-th (from 1) ``[[limit]]`` table, checked: a one-line OrdervibError naming it."""
    what = f"{source}: [[limit]] {k}"
    if not isinstance(d, dict):
        raise OrdervibError(f"{what} is not a table")
    unknown = sorted(set(d) - LIMIT_KEYS)
    if unknown:
        raise OrdervibError(f"{what}: unknown key(s) {', '.join(unknown)} (a limit has "
                            f"{', '.join(sorted(LIMIT_KEYS))})")
    target = d.get("target")
    if not isinstance(target, str) or not is_name(target) or target in RESERVED_NAMES:
        raise OrdervibError(f"{what}: target must name a channel, got {target!r}")
    what = f"{what} ({target})"

    def number(key: str, positive: bool) -> float | None:
        v = d.get(key)
        if v is None:
            return None
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        if not ok or (v <= 0 if positive else v < 0):
            want = "a positive finite number" if positive else "a finite number >= 0"
            raise OrdervibError(f"{what}: {key} must be {want}, got {v!r}")
        return float(v)

    if "max" not in d:
        raise OrdervibError(f"{what}: no max")
    top = number("max", True)
    lo, hi = number("from_speed", False), number("to_speed", False)
    oc = d.get("oc")
    if oc is not None and not isinstance(oc, str):
        raise OrdervibError(f"{what}: oc must be an OC's name, got {oc!r}")
    if oc is not None and (lo is not None or hi is not None):
        raise OrdervibError(f"{what}: gives both a speed band and an oc (one or the other)")
    if lo is not None and hi is not None and not lo < hi:
        raise OrdervibError(f"{what}: inverted speed band, from_speed {lo:g} is not below to_speed {hi:g}")
    assert top is not None
    return Limit(target, top, lo, hi, oc)


@dataclass(frozen=True)
class Schedule:
    """OCs in test order; ``switch`` names the speed channel, ``tolerance`` the
    relative band around a plateau speed that counts as steady.

    ``names`` and ``ocs`` are the plateaus; ``segments`` the names of everything monitored: the
    OCs (the first one's transition is the start, from light-off) and then ``RUNDOWN``, whose
    index is ``len(ocs)``.

    >>> s = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))
    >>> s.segments, s.index("B"), s.index(RUNDOWN), s.models[s.start]
    (('A', 'B', 'rundown'), 1, 2, 'A:start')

    ``limits``: the acceptance limits (``[[limit]]``), each on a segment of ``segments`` where it
    names one; ``separation_margin``: the critical speeds' least separation from the plateau
    speeds, a fraction of the plateau speed (API 684; None: none given).
    """

    ocs: tuple[OperatingCondition, ...]
    switch: str = "nB"
    tolerance: float = 0.02
    limits: tuple[Limit, ...] = ()
    separation_margin: float | None = None

    def __post_init__(self) -> None:
        if not self.ocs:
            raise OrdervibError("schedule has no [[oc]] entries")
        if not 0 < self.tolerance < 0.5:
            raise OrdervibError(f"schedule tolerance must be in (0, 0.5), got {self.tolerance}")
        names = [oc.name for oc in self.ocs]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise OrdervibError(f"schedule repeats OC name(s) {sorted(dup)}")
        if RUNDOWN in names:
            raise OrdervibError(f"schedule names an OC {RUNDOWN!r}: that name is reserved for the "
                                "segment after the last plateau")
        if start_name(names[0]) in names:
            raise OrdervibError(f"schedule names an OC {start_name(names[0])!r}: that name is reserved "
                                "for the first OC's start")
        for oc in self.ocs:
            if not oc.speed > 0:
                raise OrdervibError(f"OC {oc.name!r} has a non-positive speed {oc.speed}")
        if len(self.limits) > MAX_LIMITS:
            raise OrdervibError(f"schedule holds {len(self.limits)} [[limit]] tables, at most {MAX_LIMITS}")
        for k, lim in enumerate(self.limits, 1):
            if lim.oc is not None and lim.oc not in self.segments:
                raise OrdervibError(f"schedule: [[limit]] {k} ({lim.target}): oc {lim.oc!r} is none of the "
                                    f"schedule's segments ({', '.join(self.segments)})")
        m = self.separation_margin
        if m is not None and not 0 < m < 1:
            raise OrdervibError(f"schedule separation_margin must be in (0, 1) (a fraction of the plateau "
                                f"speed), got {m}")

    def limits_of(self, target: str) -> tuple[Limit, ...]:
        """The limits on ``target``, in the file's order."""
        return tuple(lim for lim in self.limits if lim.target == target)

    def check_targets(self, targets: Sequence[str]) -> None:
        """A limit on a channel that is none of ``targets`` (a model's) is a one-line OrdervibError."""
        unknown = sorted({lim.target for lim in self.limits} - set(targets))
        if unknown:
            raise OrdervibError(f"schedule: [[limit]] on {', '.join(unknown)}, which the model does not "
                                f"hold (its targets: {', '.join(targets)})")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(oc.name for oc in self.ocs)

    @property
    def segments(self) -> tuple[str, ...]:
        """The monitored segments' names: the OCs', then ``RUNDOWN`` (index ``len(ocs)``)."""
        return (*self.names, RUNDOWN)

    @property
    def rundown(self) -> int:
        """The rundown's segment index (``len(ocs)``)."""
        return len(self.ocs)

    @property
    def models(self) -> tuple[str, ...]:
        """The names of the models a bundle holds: ``segments``, then the start's (index
        ``len(ocs) + 1``, ``start``): the first OC's transition from light-off until it leaves the
        speed it held (idle) has a model of its own, the OC's from there, as a transition
        from a held speed (the node's ``oc`` is the first OC's in both)."""
        return (*self.segments, start_name(self.names[0]))

    @property
    def start(self) -> int:
        """The start's model index (``len(ocs) + 1``, see ``models``)."""
        return len(self.ocs) + 1

    def index(self, name: str) -> int:
        """The index of an OC name, ``RUNDOWN`` or the start's model (``models``; ValueError: none)."""
        return self.models.index(name)

    def to_dict(self) -> dict:
        """As JSON (a bundle's): limits and margin only where given (older readers ignore them)."""
        d: dict = {"switch": self.switch, "tolerance": self.tolerance,
                   "oc": [{"name": oc.name, "speed": oc.speed} for oc in self.ocs]}
        if self.limits:
            d["limit"] = [lim.to_dict() for lim in self.limits]
        if self.separation_margin is not None:
            d["separation_margin"] = self.separation_margin
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "schedule") -> Schedule:
        try:
            ocs = tuple(OperatingCondition(str(o["name"]), float(o["speed"])) for o in d["oc"])
            switch, tolerance = str(d.get("switch", "nB")), float(d.get("tolerance", 0.02))
        except (KeyError, TypeError, ValueError) as exc:
            raise OrdervibError(f"{source}: not a pass-off schedule ({exc!r}): each [[oc]] needs "
                                "a name and a speed") from None
        tables = d.get("limit", [])
        if not isinstance(tables, list):
            raise OrdervibError(f"{source}: limit must be an array of tables ([[limit]])")
        if len(tables) > MAX_LIMITS:
            raise OrdervibError(f"{source}: {len(tables)} [[limit]] tables, at most {MAX_LIMITS}")
        limits = tuple(_limit(t, k, source) for k, t in enumerate(tables, 1))
        margin = d.get("separation_margin")
        if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float))):
            raise OrdervibError(f"{source}: separation_margin must be a number, got {margin!r}")
        return cls(ocs, switch, tolerance, limits, None if margin is None else float(margin))

    def to_toml(self) -> str:
        lines = [f'switch = "{self.switch}"', f"tolerance = {self.tolerance}"]
        if self.separation_margin is not None:
            lines.append(f"separation_margin = {self.separation_margin}")
        lines.append("")
        for oc in self.ocs:
            lines += ["[[oc]]", f'name = "{oc.name}"', f"speed = {oc.speed}", ""]
        for lim in self.limits:
            lines += ["[[limit]]", *(f"{k} = {v!r}".replace("'", '"') for k, v in lim.to_dict().items()), ""]
        return "\n".join(lines)


def load_schedule(path: str | os.PathLike) -> Schedule:
    """Read a schedule TOML file; a bad file is an OrdervibError with one line."""
    try:
        with open(path, "rb") as f:
            d = tomllib.load(f)
    except FileNotFoundError:
        raise OrdervibError(f"schedule file not found: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise OrdervibError(f"{path}: not valid TOML ({exc})") from None
    return Schedule.from_dict(d, str(path))
