"""The fleet's transients learnt from the training runs (``node.models.transients``).

Each training run goes through the node's own ``TransientWatch`` (the very analysis the node
runs, sample by sample, on the same channels), and each critical it finds is kept under its
transition's kind. Per kind the criticals are grouped into resonances (sorted by speed, a new
one where the next lies more than ``JOIN_PCT`` % above the group's mean) and each resonance
keeps the mean, standard deviation and count of its critical speed (rpm of the switch channel)
and AF.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from node.contract import CHANNEL_UNITS, ORDER_CHANNELS, SPEED_CHANNELS, phase_channel
from node.contract.schedule import Schedule
from node.models.transients import JOIN_PCT, FleetStat, FleetTransients, Kind, Resonance, TransientSettings
from node.runtime.tracker_lag import LagEstimate, LagFit, combine, ramp_lags
from node.runtime.transient import find_transitions
from node.runtime.transient_watch import VELOCITY_UNIT, TransientWatch
from node.training.runs import Run

log = logging.getLogger(__name__)


def transient_settings(runs: Sequence[Run], schedule: Schedule, target: str,
                       **kw: Any) -> TransientSettings:
    """The analysis of ``target``'s transitions: on its own shaft's speed where every run holds it
    (a tracked order: yA on nA, ...; else the switch channel), with its phase where every run
    holds that; ``kw``: further settings (tracker_s, k_sigma, ...)."""
    own = SPEED_CHANNELS[ORDER_CHANNELS.index(target)] if target in ORDER_CHANNELS else None
    held = own is not None and own != schedule.switch and all(own in r.channels for r in runs)
    speed = own if held else None
    phase = bool(runs) and all(phase_channel(target) in r.channels for r in runs)
    return TransientSettings(speed=speed, phase=phase, **kw)


MAX_LAG_FITS = 24  # crossings fitted for the tracker's lag (enough for its median; bounded time)


def tracker_lag(runs: Sequence[Run], schedule: Schedule, targets: Sequence[str],
                settings: dict[str, TransientSettings] | None = None,
                most: int = MAX_LAG_FITS) -> tuple[LagEstimate | None, list[LagFit]]:
    """The order tracker's lag estimated from the runs' resonance crossings (``node.runtime.
    tracker_lag``): every ramp of the switch channel, per target with a phase channel on the
    speed its settings name (default ``transient_settings``'), until ``most`` crossings pin
    it; pooled over the targets (one vibration unit). The estimate (None: no crossing pinned
    it) and every crossing fitted."""
    fits: list[LagFit] = []
    for run in runs:
        if schedule.switch not in run.channels:
            continue
        spans = find_transitions(run.column(schedule.switch))
        for target in targets:
            st = (settings or {}).get(target) or transient_settings(runs, schedule, target)
            ph = phase_channel(target)
            if not st.phase or ph not in run.channels or target not in run.channels:
                continue
            speed = run.column(st.speed or schedule.switch)
            amp, phase = run.column(target), run.column(ph)
            velocity = CHANNEL_UNITS.get(target) == VELOCITY_UNIT
            for sp in spans:
                part = slice(sp.start, sp.stop)
                fits += ramp_lags(speed[part], amp[part], phase[part], velocity=velocity,
                                  min_amplitude=st.min_amplitude)
                if sum(f.identified for f in fits) >= most:
                    return combine(fits), fits
    return combine(fits), fits


def run_transients(run: Run, schedule: Schedule, target: str, settings: TransientSettings,
                   fleet: FleetTransients | None = None) -> list[dict]:
    """The transient messages the node would publish over one run (its last transition at its
    end), against ``fleet`` if given."""
    watch = TransientWatch(target, schedule, fleet, settings)
    nan = np.full(len(run.t), np.nan)
    col = {c: run.column(c) if c in run.channels else nan for c in {watch.speed, schedule.switch, target}}
    ph = phase_channel(target)
    phase = run.column(ph) if settings.phase and ph in run.channels else None
    speed, switch, amp = col[watch.speed].tolist(), col[schedule.switch].tolist(), col[target].tolist()
    t = run.t.tolist()
    phases = phase.tolist() if phase is not None else [None] * len(t)
    ended = [watch.step(t[k], speed[k], switch[k], amp[k], phases[k]) for k in range(len(t))]
    ended.append(watch.end())
    return [m for m in ended if isinstance(m, dict)]  # (the watch analyses at once: never deferred)


def group(criticals: Sequence[tuple[float, ...]],
          join_pct: float = JOIN_PCT) -> list[list[tuple[float, ...]]]:
    """Criticals (shaft speed, ...) grouped into resonances: sorted by speed, a new group where one
    lies more than ``join_pct`` % above the current group's mean speed.

    >>> [len(g) for g in group([(9650, 15), (4500, 7), (9600, 16), (4520, 7), (8400, 14)])]
    [2, 1, 2]
    """
    out: list[list[tuple[float, ...]]] = []
    for c in sorted(criticals):
        if out:
            mean = sum(x[0] for x in out[-1]) / len(out[-1])
            if c[0] <= mean * (1 + join_pct / 100.0):
                out[-1].append(c)
                continue
        out.append([c])
    return out


def fleet_transients(runs: Sequence[Run], schedule: Schedule, target: str,
                     settings: TransientSettings | None = None) -> FleetTransients:
    """The fleet's transients of ``target`` over ``runs`` (settings: ``transient_settings``'s)."""
    settings = settings or transient_settings(runs, schedule, target)
    seen: dict[str, int] = defaultdict(int)
    found: dict[str, list[tuple[float, ...]]] = defaultdict(list)
    for run in runs:
        for m in run_transients(run, schedule, target, settings):
            seen[m["kind"]] += 1
            found[m["kind"]] += [(c["shaft_speed"], c["af"], c["speed"]) for c in m["criticals"]
                                 if c["speed"] is not None and c["af"] is not None]
    kinds = {}
    for kind, n in sorted(seen.items()):
        res = tuple(Resonance(FleetStat.of([x[2] for x in g]), FleetStat.of([x[0] for x in g]),
                              FleetStat.of([x[1] for x in g])) for g in group(found[kind]))
        kinds[kind] = Kind(n, res)
    log.info("transients of %s: %d transition(s) of %d kind(s), %d resonance(s)", target,
             sum(seen.values()), len(kinds), sum(len(k.resonances) for k in kinds.values()))
    return FleetTransients(settings, kinds)
