"""The engine's history as derived model inputs (appendix A.2.5, figure A.5); no I/O.

Run to run, an engine's vibration depends on what it went through before: how
long and how fast it ran, how long it stood since (a rotor left standing hot
bows, and the bow fades as it soaks), how warm it still is at light-off. The
gas-path inputs of one OC do not carry this. ``HistoryTracker`` derives, per
sample, causally, four channels (``HISTORY_CHANNELS``):

* ``hist_energy``: the cumulative energy parameter corrected for the shutdown
  time, the text's ς_norm, in rpm min. Within an engine run it grows by
  ∫ nB dt; while the engine stands it falls by ``cooling`` (rpm min per hour
  of shutdown), never below 0 (a cold engine carries nothing). The text's
  ς_norm = ς − (4.5e5 / 12) θ_shutdown is this rule with one engine's
  constant; here ``cooling`` is estimated from training runs
  (:func:`estimate_cooling`).
* ``hist_rate``: the cumulative rate of change of speed ξ since light-off, rpm:
  the sum of |change| of the speed's one-second means (the text's
  Σ dRPM/dt would telescope to the speed itself; its absolute value is what
  figure A.5 (c) accumulates, and one-second means keep noise from adding up).
* ``hist_shutdown``: the shutdown time before this engine run, hours (the time
  since the engine last ran, growing while it stands; frozen at light-off;
  ``SHUTDOWN_CAP_H`` when unknown or longer: a cold engine).
* ``hist_thermal``: the thermal state at light-off, °C: the mean of the slow
  temperatures (the schedule's ``tF``, ``tI``, ``tH``) at the light-off sample
  (NaN before the first light-off).

The engine runs while its switch speed is at or above ``on_speed`` (the OC
detector's off level). What survives between runs (and node restarts) is an
:class:`EngineState`, small enough for a JSON state file. The node
(``MonitorPipeline``) and training (``add_history``) step the very same object,
so both see the same numbers to the last bit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.models.config import RuntimeConfig
from node.runtime.runcurve import hold_last

HISTORY_CHANNELS = ("hist_energy", "hist_rate", "hist_shutdown", "hist_thermal")
SLOW_TEMPERATURES = ("tF", "tI", "tH")  # the slow gas-path temperatures of the thermal state
SHUTDOWN_CAP_H = 24.0  # a shutdown longer than this (or unknown) counts as this long: cold
TEXT_COOLING = RuntimeConfig.history_cooling  # the text's 4.5e5 / 12 rpm min per hour
_SAME_RUN_S = 60.0  # the engine off for less than this: the same engine run continues
_NAN = math.nan


@dataclass
class EngineState:
    """What one engine's history carries between runs (and a state file keeps).

    Attributes:
        last_on_t: time of the last sample the engine ran, s since the epoch (None: unknown).
        energy: ``hist_energy`` at that sample, rpm min.
        shutdown_h, thermal, rate: ``hist_shutdown``, ``hist_thermal`` and ``hist_rate`` of
            that engine run (so that a node restarted inside a run carries on with them).

    >>> EngineState.from_dict(EngineState(12.5, 3.0).to_dict())
    EngineState(last_on_t=12.5, energy=3.0, shutdown_h=24.0, thermal=None, rate=0.0)
    >>> EngineState.from_dict({"last_on_t": "x", "energy": 1.0})
    Traceback (most recent call last):
    ...
    ValueError: last_on_t must be a finite number or null, got 'x'
    """

    last_on_t: float | None = None
    energy: float = 0.0
    shutdown_h: float = SHUTDOWN_CAP_H
    thermal: float | None = None  # None: not measured (NaN as a channel)
    rate: float = 0.0

    def to_dict(self) -> dict[str, float | None]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: object) -> EngineState:
        """From a state file's object; a malformed one is a ValueError naming the field."""
        if not isinstance(d, dict):
            raise ValueError(f"an engine state must be an object, got {type(d).__name__}")
        unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"unknown engine state field(s): {', '.join(unknown)}")
        out = cls()
        for name in ("last_on_t", "thermal"):
            v = d.get(name)
            if v is not None and not _finite(v):
                raise ValueError(f"{name} must be a finite number or null, got {v!r}")
            setattr(out, name, None if v is None else float(v))
        for name in ("energy", "shutdown_h", "rate"):
            v = d.get(name, getattr(out, name))
            if not _finite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
            setattr(out, name, float(v))
        return out


def _finite(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


class HistoryTracker:
    """Stateful per engine; memory: a few numbers.

    Args:
        on_speed: the engine runs at or above this switch speed (rpm).
        cooling: ``hist_energy`` lost per hour the engine stands, rpm min per h.
        state: the history so far (default: nothing known, a cold engine); the tracker
            keeps it up to date (``tracker.state``).

    Two runs at 6000 rpm, 30 minutes apart (cooling 100 rpm min per hour):

    >>> h = HistoryTracker(on_speed=500.0, cooling=100.0)
    >>> for k in range(80):
    ...     out = h.step(k / 40, 6000.0, (20.0, 30.0, 40.0))
    >>> [round(v, 3) for v in out]  # 80 samples x 6000 rpm / 40 Hz / 60 s
    [200.0, 0.0, 24.0, 30.0]
    >>> out = h.step(1800.0 + 79 / 40, 6000.0, (20.0, 30.0, 40.0))
    >>> [round(v, 3) for v in out]  # 200 - 0.5 h x 100, then one sample
    [152.5, 0.0, 0.5, 30.0]
    """

    def __init__(self, on_speed: float, cooling: float = TEXT_COOLING,
                 state: EngineState | None = None) -> None:
        if not (math.isfinite(on_speed) and on_speed > 0):
            raise ValueError(f"on_speed must be a positive number, got {on_speed!r}")
        if not (math.isfinite(cooling) and cooling >= 0):
            raise ValueError(f"cooling must be a finite number >= 0, got {cooling!r}")
        self.on_speed = float(on_speed)
        self.cooling = float(cooling)
        self.state = EngineState() if state is None else dataclasses.replace(state)
        self.light_offs = 0  # engine runs begun (not continued) while this tracker ran
        self._last: tuple[float, tuple[float, float, float, float]] | None = None  # (t, values)
        self._on = False
        self._block_sum = 0.0
        self._block_n = 0
        self._block_prev = _NAN
        self._per_sample = 1.0 / (FS * 60.0)  # rpm per sample -> rpm min

    def _standing_h(self, t: float) -> float:
        last = self.state.last_on_t
        if last is None or not t >= last:
            return SHUTDOWN_CAP_H
        return min((t - last) / 3600.0, SHUTDOWN_CAP_H)

    def _light_off(self, t: float, slow: Sequence[float]) -> None:
        st = self.state
        self._on = True
        if st.last_on_t is not None and 0.0 <= t - st.last_on_t < _SAME_RUN_S:
            return  # a short dip below the off level, or a restarted node: the same engine run
        st.shutdown_h = self._standing_h(t)
        st.energy = max(0.0, st.energy - self.cooling * st.shutdown_h)
        st.thermal = math.fsum(slow) / len(slow) if all(x == x for x in slow) else None
        st.rate = 0.0
        self._block_sum, self._block_n, self._block_prev = 0.0, 0, _NAN
        self.light_offs += 1

    def step(self, t: float, speed: float, slow: Sequence[float]) -> tuple[float, float, float, float]:
        """This sample's (hist_energy, hist_rate, hist_shutdown, hist_thermal).

        t: sample time, s; speed: the switch speed, rpm (NaN: unknown, the engine's state
        is kept); slow: the slow temperatures (tF, tI, tH), °C (held over dropouts by the caller).
        A second call for the same t (another target's pipeline of the same bed) returns the
        first call's values and changes nothing.
        """
        last = self._last
        if last is not None and last[0] == t:
            return last[1]
        out = self._advance(t, speed, slow)
        self._last = (t, out)
        return out

    def _advance(self, t: float, speed: float, slow: Sequence[float]
                 ) -> tuple[float, float, float, float]:
        st = self.state
        if speed >= self.on_speed:
            if not self._on or (st.last_on_t is not None and not t - st.last_on_t < _SAME_RUN_S):
                self._light_off(t, slow)  # (the second: a gap in the data, the engine stood)
            st.energy += speed * self._per_sample
            self._block_sum += speed
            self._block_n += 1
            if self._block_n == int(FS):
                mean = self._block_sum / self._block_n
                if self._block_prev == self._block_prev:
                    st.rate += abs(mean - self._block_prev)
                self._block_prev, self._block_sum, self._block_n = mean, 0.0, 0
            st.last_on_t = t
            energy, shutdown = st.energy, st.shutdown_h
        else:
            if speed == speed:
                self._on = False
            shutdown = self._standing_h(t)
            energy = max(0.0, st.energy - self.cooling * shutdown) if not self._on else st.energy
        return energy, st.rate, shutdown if not self._on else st.shutdown_h, \
            _NAN if st.thermal is None else st.thermal


def history_columns(t: np.ndarray, speed: np.ndarray, slow: np.ndarray, tracker: HistoryTracker
                    ) -> np.ndarray:
    """The four channels over one run, stepping ``tracker`` as the node does: (K, 4).

    t (K,) s; speed (K,) rpm and slow (K, 3) °C, held over dropouts as the node holds them.
    """
    out = np.empty((len(t), len(HISTORY_CHANNELS)))
    step = tracker.step
    for k, (tk, s, row) in enumerate(zip(np.asarray(t, float).tolist(), np.asarray(speed, float).tolist(),
                                         np.asarray(slow, float).tolist())):
        out[k] = step(tk, s, row)
    return out


def _run_inputs(run, switch: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, speed, slow (K, 3)) of a run, held over dropouts as the node holds them."""
    k = len(run.t)
    speed = hold_last(np.asarray(run.column(switch), float))
    slow = np.column_stack([hold_last(np.asarray(run.column(c), float)) if c in run.channels
                            else np.full(k, np.nan) for c in SLOW_TEMPERATURES])
    return np.asarray(run.t, float), speed, slow


def add_history(runs: list, switch: str, on_speed: float, cooling: float,
                state: EngineState | None = None) -> list:
    """``runs`` (``node.mcap.Run``, in time order, one engine) with the four channels appended,
    one tracker stepped through them all as the node steps it (``state``: the history before)."""
    tracker = HistoryTracker(on_speed, cooling, state)
    out = []
    for run in runs:
        if switch not in run.channels or any(c in run.channels for c in HISTORY_CHANNELS):
            out.append(run)
            continue
        cols = history_columns(*_run_inputs(run, switch), tracker)
        out.append(dataclasses.replace(run, data=np.column_stack([run.data, cols]),
                                       channels=(*run.channels, *HISTORY_CHANNELS)))
    return out


def state_after(runs: list, switch: str, on_speed: float, cooling: float,
                state: EngineState | None = None) -> EngineState:
    """The engine's history at the end of ``runs`` (``node.mcap.Run``, in time order, one
    engine), stepped through them as the node steps it from ``state`` (default: unknown)."""
    tracker = HistoryTracker(on_speed, cooling, state)
    for run in runs:
        if switch in run.channels:
            history_columns(*_run_inputs(run, switch), tracker)
    return dataclasses.replace(tracker.state)


COOLING_GRID = (1e2, 1e7)  # the cooling rates estimate_cooling searches, rpm min per hour


def estimate_cooling(runs: list, switch: str, on_speed: float, min_runs: int = 3) -> float | None:
    """The cooling rate (rpm min per hour of shutdown) that makes ``hist_energy`` at light-off
    follow the thermal state measured then, over training runs (in time order, one engine).

    The engine's warmth at light-off is measured by the slow temperatures (``hist_thermal``);
    the energy it carries then is the previous run's energy less ``cooling`` per hour stood.
    Over the light-offs that follow a known run, the rate whose carried energy correlates
    best (Pearson) with the measured thermal state is returned, searched on a log grid from
    1e2 to 1e7 rpm min per hour (the text's one-engine value is 3.75e4). None when fewer than
    ``min_runs`` such light-offs have a thermal state, or none correlates positively.
    """
    tracker = HistoryTracker(on_speed, cooling=0.0)
    events: list[tuple[float, float, float]] = []  # (energy at light-off uncooled, shutdown h, thermal)
    for run in runs:
        if switch not in run.channels:
            continue
        t, speed, slow = _run_inputs(run, switch)
        seen = tracker.light_offs
        for tk, s, row in zip(t.tolist(), speed.tolist(), slow.tolist()):
            st = tracker.state
            before = st.energy
            tracker.step(tk, s, row)
            if tracker.light_offs != seen:
                seen = tracker.light_offs
                if st.thermal is not None:
                    events.append((before, st.shutdown_h, st.thermal))
    # with cooling 0 the energy at each light-off is the running total: replay it per rate
    gains = np.diff([e for e, _, _ in events], prepend=0.0)  # energy run between light-offs
    known = np.array([h < SHUTDOWN_CAP_H for _, h, _ in events])
    if int(known.sum()) < min_runs:
        return None
    thermal = np.array([th for _, _, th in events])
    best: tuple[float, float] | None = None
    for rate in np.logspace(math.log10(COOLING_GRID[0]), math.log10(COOLING_GRID[1]), 51):
        carried, e = [], 0.0
        for gain, (_, h, _) in zip(gains, events):
            e = max(0.0, e + gain - rate * h)
            carried.append(e)
        x = np.array(carried)[known]
        if np.ptp(x) == 0:
            continue
        r = float(np.corrcoef(x, thermal[known])[0, 1])
        if r > 0 and (best is None or r > best[0]):
            best = (r, float(rate))
    return None if best is None else best[1]
