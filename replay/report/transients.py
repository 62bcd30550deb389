"""Panel V of the report: the transients, as a rotordynamics engineer reads them.

Every run goes through the node's own transient analysis (``node.training.transients.
run_transients``: the ``monitor/transient`` messages the node publishes, sample by sample, with
the model's settings and its fleet of criticals where the bundle keeps one): each resonance
crossed in each ramp with its critical speed (rpm of the switch channel), peak amplitude, phase
change, AF by the half-power method, and against the fleet its expected speed, shift and flag.
The crossings are grouped into resonances as training groups them (``group``), each with its
spread over the runs and its separation margin from the nearest OC's plateau speed (API 684's
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
from node.models.bundle import Bundle
from node.training.runs import Run
from node.training.transients import group, run_transients, transient_settings
from replay.report.document import Block, Figure, Paragraph, Table
from replay.views.phase_plots import bode_figure
from replay.views.view_data import Vectors


@dataclass(frozen=True)
class Crossing:
    """One resonance crossed in one ramp of one run: the run's index, its transient message
    (``monitor/transient``) and the critical's entry in it."""

    run: int
    message: dict
    critical: dict


def separation(nc: float, ocs: Sequence[tuple[str, float]]) -> tuple[str, float, float]:
    """The OC whose plateau speed is nearest ``nc``: (name, speed, margin in % of that speed)."""
    name, speed = min(ocs, key=lambda o: abs(o[1] - nc))
    return name, speed, 100.0 * abs(speed - nc) / speed


def crossings(runs: Sequence[Run], schedule: Schedule, target: str, bundle: Bundle | None = None
              ) -> list[Crossing]:
    """Every critical the node's transient analysis finds in ``runs`` (with the bundle's settings
    and fleet; None or a bundle without them: the settings training would choose, no fleet)."""
    fleet = bundle.transients if bundle is not None else None
    settings = fleet.settings if fleet is not None else transient_settings(runs, schedule, target)
    out: list[Crossing] = []
    for r, run in enumerate(runs):
        if schedule.switch not in run.channels or target not in run.channels:
            continue
        for m in run_transients(run, schedule, target, settings, fleet):
            out += [Crossing(r, m, c) for c in m["criticals"] if c["speed"] is not None]
    return out


def resonances(found: Sequence[Crossing]) -> list[list[Crossing]]:
    """The crossings grouped by critical speed as training groups the fleet's (``group``)."""
    by_speed = group([(c.critical["speed"], k) for k, c in enumerate(found)])
    return [[found[int(k)] for _, k in g] for g in by_speed]


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
                    bundle: Bundle | None = None, unit: str = "mm/s") -> list[Block]:
    """V: the Bode figure of every run's ramps, the resonances over the runs and every crossing."""
    sw = schedule.switch
    found = crossings(runs, schedule, target, bundle)
    has_phase = any(phase_channel(target) in r.channels for r in runs)
    how = "its 1x vector (amplitude and phase)" if has_phase else "its amplitude alone (no phase channel)"
    fleet = bundle is not None and bundle.transients is not None
    blocks: list[Block] = [Paragraph(
        f"Each ramp of each run (run-ups, ramps between plateaus, coast-downs) analysed as the node "
        f"analyses it for its monitor/transient messages, from {target}'s {how}: every resonance "
        f"crossed, its critical speed in rpm of {sw}, peak amplitude, phase change and amplification "
        "factor by the half-power method (API 684: AF = Nc / (N2 - N1)), "
        + ("against the model's fleet of criticals (expected speed, shift, flag). " if fleet else
           "no fleet to compare with (the model keeps none). ")
        + "Separation margin: |N_op - Nc| / N_op from the nearest OC's plateau speed; the margin a "
        "standard requires depends on the AF and is not judged here.")]
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
        nc = np.array([c.critical["speed"] for c in g])
        af = np.array([c.critical["af"] if c.critical["af"] is not None else np.nan for c in g])
        name, speed, margin = separation(float(np.mean(nc)), ocs)
        afs = (f"{np.nanmean(af):.1f} ({np.nanmin(af):.1f}-{np.nanmax(af):.1f})" if np.isfinite(af).any()
               else "-")
        rows.append([f"{np.mean(nc):,.0f}", f"{np.std(nc):,.0f} ({100 * np.std(nc) / np.mean(nc):.2f} %)",
                     str(len(g)), f"{len({c.run for c in g})}", afs, f"{name} ({speed:,.0f})",
                     f"{margin:.1f} %"])
    blocks.append(Table([f"critical, {sw} rpm (mean)", "spread (std)", "crossings", "runs",
                         "AF mean (range)", "nearest OC (rpm)", "separation margin"], rows,
                        f"{target}: resonances over the runs (grouped as training groups the fleet's)"))
    detail = []
    for c in sorted(found, key=lambda x: (x.run, x.message["t"], x.critical["speed"])):
        m, k = c.message, c.critical
        detail.append([labels[c.run] if c.run < len(labels) else str(c.run + 1),
                       str(m.get("kind", m["direction"])),
                       f"{_num(m['from_speed'], ',.0f')} -> {_num(m['to_speed'], ',.0f')}",
                       _num(k["speed"], ",.0f"), _num(k["amplitude"], ".2f"), _num(k["phase_change"], ".0f"),
                       _num(k["af"], ".1f"), _num(k.get("expected_speed"), ",.0f"),
                       _num(k.get("shift"), "+.2f"), str(getattr(m["flag"], "value", m["flag"]))])
    blocks.append(Table(["run", "transition", f"{sw} (rpm)", "critical (rpm)", f"peak ({unit})",
                         "phase change (°)", "AF", "fleet's (rpm)", "shift (%)", "flag"], detail,
                        f"{target}: every resonance crossed (as the node's monitor/transient messages)"))
    return blocks
