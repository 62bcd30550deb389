"""Panel V of the report: the transients, as a rotordynamics engineer reads them.

Every ramp of every run (``node.runtime.transient.find_transitions`` on the switch speed) is
analysed (``transient.analyse``: the target's 1x vector where the runs hold its phase channel,
else its amplitude): each resonance crossed with its critical speed (rpm of the switch
channel), peak amplitude, phase change and AF by the half-power method. The crossings are
grouped into resonances (criticals within ``GROUP_SPAN`` of each other), each with its spread
over the runs and its separation margin from the nearest OC's plateau speed (API 684's
|N_op - N_c| / N_op; the margin a standard requires depends on the AF and is not judged here).
The Bode figure is ``ordervib view --plots``' own (``replay.views.phase_plots``).

>>> separation(8000.0, [("OC7", 8100.0), ("OC13", 5200.0)])
('OC7', 8100.0, 1.2345679012345678)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import phase_channel
from node.contract.schedule import Schedule
from node.runtime.transient import Critical, analyse, find_transitions
from node.training.runs import Run
from replay.report.document import Block, Figure, Paragraph, Table
from replay.views.phase_plots import bode_figure
from replay.views.view_data import Vectors

GROUP_SPAN = 0.03  # crossings whose criticals lie within 3 % of the group's first are one resonance
MIN_SAMPLES = 40  # a ramp shorter than 1 s at 40 Hz is not analysed


@dataclass(frozen=True)
class Crossing:
    """One resonance crossed in one ramp of one run (speeds in rpm of the switch channel)."""

    run: int
    direction: str
    from_speed: float
    to_speed: float
    critical: Critical


def separation(nc: float, ocs: Sequence[tuple[str, float]]) -> tuple[str, float, float]:
    """The OC whose plateau speed is nearest ``nc``: (name, speed, margin in % of that speed)."""
    name, speed = min(ocs, key=lambda o: abs(o[1] - nc))
    return name, speed, 100.0 * abs(speed - nc) / speed


def crossings(runs: Sequence[Run], switch: str, target: str, tracker_tau: float = 0.0) -> list[Crossing]:
    """Every resonance found in every ramp of ``runs`` (with the target's phase where a run has it)."""
    out: list[Crossing] = []
    ph_name = phase_channel(target)
    for r, run in enumerate(runs):
        if switch not in run.channels or target not in run.channels:
            continue
        speed, amp = run.column(switch), run.column(target)
        phase = run.column(ph_name) if ph_name in run.channels else None
        for sp in find_transitions(speed):
            sl = slice(sp.start, sp.stop)
            if sp.stop - sp.start < MIN_SAMPLES or np.isfinite(amp[sl]).sum() < MIN_SAMPLES:
                continue
            ph = phase[sl] if phase is not None and np.isfinite(phase[sl]).any() else None
            try:
                found = analyse(speed[sl], amp[sl], ph, tracker_tau=tracker_tau).criticals
            except ValueError:  # too few samples with speed and amplitude
                continue
            out += [Crossing(r, sp.direction, sp.from_speed, sp.to_speed, c) for c in found]
    return out


def resonances(found: Sequence[Crossing]) -> list[list[Crossing]]:
    """The crossings grouped by critical speed (ascending; a group spans at most ``GROUP_SPAN``)."""
    groups: list[list[Crossing]] = []
    for c in sorted(found, key=lambda x: x.critical.speed):
        if groups and c.critical.speed <= groups[-1][0].critical.speed * (1.0 + GROUP_SPAN):
            groups[-1].append(c)
        else:
            groups.append([c])
    return groups


def _vectors(runs: Sequence[Run], switch: str, target: str) -> Vectors:
    """The runs' 1x vectors as the views take them (phase NaN where a run has none)."""
    ph = phase_channel(target)
    cols = [(run.t, run.column(switch), np.full(len(run.t), r), run.column(target),
             run.column(ph) if ph in run.channels else np.full(len(run.t), np.nan))
            for r, run in enumerate(runs) if switch in run.channels and target in run.channels]
    t, speed, run_no, amp, phase = (np.concatenate([c[k] for c in cols]) for k in range(5))
    nan = np.full(len(t), np.nan)
    return Vectors(t, speed, run_no, amp, phase, nan, nan)


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def transient_panel(runs: Sequence[Run], labels: Sequence[str], schedule: Schedule, target: str,
                    unit: str = "mm/s") -> list[Block]:
    """V: the Bode figure of every run's ramps, the resonances over the runs and every crossing."""
    sw = schedule.switch
    found = crossings(runs, sw, target)
    has_phase = any(phase_channel(target) in r.channels for r in runs)
    how = "its 1x vector (amplitude and phase)" if has_phase else "its amplitude alone (no phase channel)"
    blocks: list[Block] = [Paragraph(
        f"Each ramp of each run (run-ups, ramps between plateaus, coast-downs; found on {sw}) analysed "
        f"from {target}'s {how}: every resonance crossed, its critical speed in rpm of {sw}, peak "
        "amplitude, phase change and amplification factor by the half-power method (API 684: AF = "
        "Nc / (N2 - N1)). The order tracker's lag is not undone here (on a fast ramp the peak trails "
        "the critical by the ramp rate times that lag). Separation margin: |N_op - Nc| / N_op from the "
        "nearest OC's plateau speed; the margin a standard requires depends on the AF and is not judged "
        "here.")]
    if any(sw in r.channels and target in r.channels for r in runs):
        fig = bode_figure(_vectors(runs, sw, target), f"{target}", sw, target, unit)
        blocks.append(Figure.of(fig, f"Bode plot of the ramps of {len(runs)} run(s): amplitude and "
                                     f"phase lag against {sw}, criticals marked"))
    if not found:
        blocks.append(Paragraph(f"No resonance found in the ramps of {target}.", note=True))
        return blocks
    ocs = [(oc.name, oc.speed) for oc in schedule.ocs]
    rows = []
    for g in resonances(found):
        nc = np.array([c.critical.speed for c in g])
        af = np.array([c.critical.af for c in g])
        name, speed, margin = separation(float(np.mean(nc)), ocs)
        rows.append([f"{np.mean(nc):,.0f}", f"{np.std(nc):,.0f} ({100 * np.std(nc) / np.mean(nc):.2f} %)",
                     str(len(g)), f"{len({c.run for c in g})}",
                     f"{np.mean(af):.1f} ({np.min(af):.1f}-{np.max(af):.1f})",
                     f"{name} ({speed:,.0f})", f"{margin:.1f} %"])
    blocks.append(Table([f"critical, {sw} rpm (mean)", "spread (std)", "crossings", "runs",
                         "AF mean (range)", "nearest OC (rpm)", "separation margin"], rows,
                        f"{target}: resonances over the runs (crossings within {GROUP_SPAN:.0%} grouped)"))
    detail = [[labels[c.run] if c.run < len(labels) else str(c.run + 1), c.direction,
               f"{c.from_speed:,.0f} -> {c.to_speed:,.0f}", f"{c.critical.speed:,.0f}",
               _num(c.critical.amplitude, ".2f"), _num(c.critical.phase_change, ".0f"),
               _num(c.critical.af, ".1f"), _num(c.critical.zeta, ".3f"), c.critical.af_method]
              for c in sorted(found, key=lambda x: (x.run, x.critical.speed))]
    blocks.append(Table(["run", "ramp", f"{sw} (rpm)", "critical (rpm)", f"peak ({unit})", "phase change (°)",
                         "AF", "damping ratio", "AF from"], detail, f"{target}: every resonance crossed"))
    return blocks
