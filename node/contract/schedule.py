"""The pass-off schedule (docs/contract.md section 4): which OCs, in which order, at which speed."""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass

from node.contract.errors import OrdervibError

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
    """

    ocs: tuple[OperatingCondition, ...]
    switch: str = "nB"
    tolerance: float = 0.02

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
        return {"switch": self.switch, "tolerance": self.tolerance,
                "oc": [{"name": oc.name, "speed": oc.speed} for oc in self.ocs]}

    @classmethod
    def from_dict(cls, d: dict, source: str = "schedule") -> Schedule:
        try:
            ocs = tuple(OperatingCondition(str(o["name"]), float(o["speed"])) for o in d["oc"])
            return cls(ocs, str(d.get("switch", "nB")), float(d.get("tolerance", 0.02)))
        except (KeyError, TypeError, ValueError) as exc:
            raise OrdervibError(f"{source}: not a pass-off schedule ({exc!r}): each [[oc]] needs "
                                "a name and a speed") from None

    def to_toml(self) -> str:
        lines = [f'switch = "{self.switch}"', f"tolerance = {self.tolerance}", ""]
        for oc in self.ocs:
            lines += ["[[oc]]", f'name = "{oc.name}"', f"speed = {oc.speed}", ""]
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
