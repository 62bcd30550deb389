"""Unit conversions into the contract's units (``docs/contract.md`` section 1), a short fixed table.

A conversion is affine: contract value = source value x scale + offset. Each contract unit
(``node.contract.CHANNEL_UNITS``) has the source units it converts from, by name; anything
else is given in the map as ``scale`` and ``offset``.

>>> conversion("nA", "rad/s")[0] * 2 * math.pi
60.0
>>> scale, offset = conversion("tA", "degF")
>>> round(212.0 * scale + offset, 9)
100.0
>>> try:
...     conversion("pA", "furlong")
... except OrdervibError as exc:
...     print(str(exc)[:90])
unit 'furlong' of pA: not one ordervib converts to kPa (bar, hPa, kPa, mbar, MPa, Pa, psi)
"""

from __future__ import annotations

import math

from node.contract import CHANNEL_UNITS, ORDER_CHANNELS, OrdervibError

_PSI_KPA = 6.894757293168361  # kPa per psi (lbf/in^2)
_F = 5.0 / 9.0

# contract unit -> source unit -> (scale, offset)
CONVERSIONS: dict[str, dict[str, tuple[float, float]]] = {
    "rpm": {"rpm": (1.0, 0.0), "RPM": (1.0, 0.0), "1/min": (1.0, 0.0), "rev/min": (1.0, 0.0),
            "rad/s": (60.0 / (2.0 * math.pi), 0.0), "Hz": (60.0, 0.0), "krpm": (1000.0, 0.0)},
    "mm/s": {"mm/s": (1.0, 0.0), "in/s": (25.4, 0.0), "ips": (25.4, 0.0), "m/s": (1000.0, 0.0)},
    "degC": {"degC": (1.0, 0.0), "°C": (1.0, 0.0), "C": (1.0, 0.0),
             "degF": (_F, -32.0 * _F), "°F": (_F, -32.0 * _F), "F": (_F, -32.0 * _F),
             "K": (1.0, -273.15)},
    "kPa": {"kPa": (1.0, 0.0), "Pa": (1e-3, 0.0), "hPa": (0.1, 0.0), "mbar": (0.1, 0.0),
            "bar": (100.0, 0.0), "MPa": (1000.0, 0.0), "psi": (_PSI_KPA, 0.0)},
    "deg": {"deg": (1.0, 0.0), "°": (1.0, 0.0), "degrees": (1.0, 0.0), "rad": (180.0 / math.pi, 0.0)},
    "": {"": (1.0, 0.0), "1": (1.0, 0.0), "-": (1.0, 0.0)},
}

# an order amplitude's detection -> the factor to the contract's peak (a sinusoid: rms x sqrt 2)
DETECTIONS: dict[str, float] = {"peak": 1.0, "rms": math.sqrt(2.0), "pk-pk": 0.5}


def conversion(channel: str, unit: str) -> tuple[float, float]:
    """(scale, offset) from ``unit`` to the unit of contract channel ``channel``; one-line
    ``OrdervibError`` for a unit the table does not know for that channel."""
    target = CHANNEL_UNITS[channel]
    table = CONVERSIONS[target]
    if unit not in table:
        known = ", ".join(sorted((u for u in table if u), key=str.lower)) or "none"
        shown = target or "a unitless signal"
        raise OrdervibError(f"unit {unit!r} of {channel}: not one ordervib converts to {shown} "
                            f"({known}); give scale and offset instead")
    return table[unit]


def same_unit(channel: str, a: str, b: str) -> bool:
    """Whether two unit names mean one unit for contract channel ``channel``: the same name, or
    names the table converts alike (rpm, RPM, 1/min). A name the table does not know is only
    itself.

    >>> same_unit("nB", "rpm", "1/min"), same_unit("nB", "rpm", "rad/s"), same_unit("nB", "U/min", "rpm")
    (True, False, False)
    """
    a, b = a.strip(), b.strip()
    if a == b:
        return True
    table = CONVERSIONS[CHANNEL_UNITS[channel]]
    return a in table and b in table and table[a] == table[b]


def detection_factor(channel: str, detection: str) -> float:
    """The factor from an order amplitude measured as ``detection`` (peak, rms, pk-pk) to peak.

    >>> detection_factor("yB", "pk-pk")
    0.5
    """
    if channel not in ORDER_CHANNELS:
        raise OrdervibError(f"detection is for the order amplitudes {', '.join(ORDER_CHANNELS)}, "
                            f"not {channel}")
    if detection not in DETECTIONS:
        raise OrdervibError(f"detection {detection!r} of {channel}: give one of {', '.join(DETECTIONS)}")
    return DETECTIONS[detection]
