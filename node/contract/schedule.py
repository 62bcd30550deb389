"""The pass-off schedule (docs/contract.md section 4): which OCs, in which order, at which speed."""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass

from node.contract.errors import OrdervibError


@dataclass(frozen=True)
class OperatingCondition:
    name: str
    speed: float  # plateau speed, in the unit of the switch channel


@dataclass(frozen=True)
class Schedule:
    """OCs in test order; ``switch`` names the speed channel, ``tolerance`` the
    relative band around a plateau speed that counts as steady."""

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
        for oc in self.ocs:
            if not oc.speed > 0:
                raise OrdervibError(f"OC {oc.name!r} has a non-positive speed {oc.speed}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(oc.name for oc in self.ocs)

    def index(self, name: str) -> int:
        return self.names.index(name)

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
