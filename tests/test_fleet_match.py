"""Criticals matched to the fleet's resonances by mode order under one common ratio, and the AF
judged: a uniform stiffness shift is matched to the right modes, a lone far critical stays new."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from node.models.transients import (
    AF_FLOOR_PCT,
    FleetStat,
    FleetTransients,
    Kind,
    Resonance,
    TransientSettings,
)

KIND = "down OC12->0%"


def _fleet(speeds: list[float], af: float = 12.0) -> FleetTransients:
    res = tuple(Resonance(FleetStat(x, 0.005 * x, 6), FleetStat(x, 0.005 * x, 6), FleetStat(af, 0.5, 6))
                for x in sorted(speeds))
    return FleetTransients(TransientSettings(), {KIND: Kind(6, res)})


@st.composite
def _modes(draw) -> list[float]:
    """2-4 modes, each at least 40 % above the one below (modes spaced by about the shift's own
    ratio are ambiguous under a common ratio: the ratio nearer 1 wins)."""
    n = draw(st.integers(2, 4))
    x = draw(st.floats(1500.0, 5000.0))
    out = [x]
    for _ in range(n - 1):
        out.append(out[-1] * draw(st.floats(1.4, 1.8)))
    return out


@settings(max_examples=150, deadline=None)
@given(_modes(), st.floats(0.88, 1.12), st.data())  # up to a 20 % stiffness loss or gain
def test_a_uniform_shift_is_matched_to_the_right_modes_in_order(modes, ratio, data):
    fleet = _fleet(modes)
    first = data.draw(st.integers(0, len(modes) - 2))
    last = data.draw(st.integers(first + 1, len(modes) - 1))  # two or more consecutive modes crossed
    noise = [data.draw(st.floats(-0.01, 0.01)) for _ in modes]
    found = [modes[j] * ratio * (1 + noise[j]) for j in range(first, last + 1)]
    got = fleet.match(KIND, found)
    assert [r.shaft.mean if r else None for r in got] == modes[first:last + 1]
    for r, x in zip(got, found):
        assert r is not None
        shift, limit = fleet.shifted(r, x, 6)
        bound = max(4 * 100 * 0.005 * math.sqrt(7 / 6), 2.5)  # k sigma of the fleet's spread, the floor
        assert limit is not None and (abs(shift) > limit) == (abs(shift) > bound)


@settings(max_examples=100, deadline=None)
@given(_modes(), st.floats(0.09, 0.19), st.booleans())  # within the common ratio's 25 % (in log)
def test_one_critical_far_from_every_mode_is_the_missed_mode_shifted_or_new(modes, off, below):
    """Alone in its transition, a critical beyond every mode's match window is the mode the
    transition missed, shifted, where that mode is crossed as a rule; new where it is not (seen
    in too few transitions of the kind) or beyond the common ratio's reach."""
    x = modes[0] * (1 - off) if below else modes[-1] * (1 + off)
    near = modes[0] if below else modes[-1]
    got = _fleet(modes).match(KIND, [x])[0]
    assert got is not None and got.shaft.mean == near
    rare = _fleet(modes)
    rare = FleetTransients(rare.settings, {KIND: Kind(20, rare.kinds[KIND].resonances)})  # seen in 6 of 20
    assert rare.match(KIND, [x]) == [None]
    far = modes[0] * 0.7 if below else modes[-1] * 1.4
    assert _fleet(modes).match(KIND, [far]) == [None]


def test_an_af_that_rose_beyond_the_fleet_is_lost_damping():
    fleet = _fleet([4500.0, 8200.0], af=12.0)
    res = fleet.match(KIND, [4510.0, 8190.0])[1]
    assert res is not None
    rise, limit = fleet.af_rise(res, 12.0 * 1.6, 6)
    assert limit is not None and limit >= AF_FLOOR_PCT and rise > limit
    rise, limit = fleet.af_rise(res, 12.0 * 1.2, 6)
    assert limit is not None and rise < limit
