"""The engineer's report of pass-off runs: the pass-off verdict (when the schedule has limits),
a summary, then the five panels, per target, as one HTML page.

``build_report`` returns the page (``replay.report.document``); ``ordervib report`` checks the
files and writes it. With acceptance limits the page opens with the verdict (``VERDICT``,
``replay.report.verdict``): per target each run's pass or fail, margin, engine, bed and date,
and the node's forecasts against what happened. The summary (``SUMMARY``,
``replay.report.summary``) comes next (first without limits), open: per target a verdict on
the model and a table of the OCs. Each panel then has a stable id (``PANELS``), a
heading numbered I-V and a line of what it holds (``GISTS``), folded in a ``<details>``;
with several targets, each holds one part per target.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence

from node import __version__
from node.models.bundle import Model
from replay.offline import NodeAlarms, node_alarms
from replay.report.document import Block, Heading, Panel, render_document
from replay.report.panels import (
    RunSet,
    Scores,
    context_panel,
    parameters_panel,
    prediction_panel,
    score_runs,
    target_episodes,
    validation_panel,
)
from replay.report.summary import summary_blocks
from replay.report.transients import transient_panel
from replay.report.verdict import VERDICT, verdict_blocks

log = logging.getLogger(__name__)

PANELS: tuple[tuple[str, str], ...] = (
    ("panel-context", "I. Contextual characteristic curve"),
    ("panel-parameters", "II. Parameter extraction"),
    ("panel-validation", "III. Validation"),
    ("panel-prediction", "IV. Prediction"),
    ("panel-transients", "V. Transients"),
)
SUMMARY = ("summary", "Summary")
GISTS = {  # each folded panel's line under its title
    "panel-context": "the characteristic curve with every run, each OC's plateau levels, the thermal "
                     "contexts (Dirichlet-process clusters) and their posteriors",
    "panel-parameters": "per OC, the model's inputs and the engine history of every run (parallel "
                        "coordinates, tables); the rho_DPCCA heatmap of every channel",
    "panel-validation": "per OC and run set, eps_td and R\u00b2 against the curve; measured against "
                        "predicted; the node's alarm episodes",
    "panel-prediction": "each run predicted without its measured order; the schedule as a planned pass-off",
    "panel-transients": "the Bode plot of every ramp; each resonance's critical speed, AF and spread over "
                        "the runs, its separation margin from the OCs",
}


def summary_panel(model: Model, runs: RunSet, targets: Sequence[str], alarms: NodeAlarms,
                  step: Callable[[], None] | None = None) -> tuple[Panel, dict[str, Scores]]:
    """The summary (open, ``SUMMARY``): per target its verdict and its table of the OCs; and the
    targets' ``Scores`` (panel III shows the same). step: called after each target."""
    scores: dict[str, Scores] = {}
    blocks: list[Block] = []
    for t in targets:
        scores[t] = score_runs(model[t], runs, model.schedule, t)
        episodes = target_episodes(alarms, runs, model.schedule, t)
        blocks += summary_blocks(model[t], runs, model.schedule, t, scores[t], episodes)
        if step is not None:
            step()
    return Panel(SUMMARY[0], SUMMARY[1], blocks, fold=False), scores


def build_report(model: Model, runs: RunSet, recordings: Sequence[str], targets: Sequence[str],
                 model_name: str = "", alarms: NodeAlarms | None = None,
                 progress: Callable[[float], None] | None = None) -> str:
    """The report's HTML page of ``runs`` (read from ``recordings``) for ``targets`` of ``model``.

    alarms: the node's alarms over the recordings (default: replayed here, ``node_alarms``, the
    engine history carried through the recordings in the order given, as panels II-IV derive it).
    progress: called with the fraction done (0..1) after each step (the replay, then each panel
    of each target).
    """
    t0 = time.perf_counter()
    steps = 1 + (len(PANELS) + 1) * len(targets)
    done = 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done / steps)

    if alarms is None:
        log.info("report: replaying the node over %d recording(s) for its alarms", len(recordings))
        alarms = node_alarms(list(recordings), model, carry=True)
    step()
    schedule = model.schedule
    log.info("report: the summary")
    summary, scores = summary_panel(model, runs, targets, alarms, step)
    makers: list[Callable[[str], list[Block]]] = [
        lambda t: context_panel(model[t], runs, schedule, t),
        lambda t: parameters_panel(model[t], runs, schedule, t),
        lambda t: validation_panel(model[t], runs, schedule, t, alarms, scores[t]),
        lambda t: prediction_panel(model[t], runs, schedule, t, scores[t].kinds),
        lambda t: transient_panel(runs.runs, runs.labels, schedule, t, model[t]),
    ]
    panels = [summary]
    if schedule.limits:
        log.info("report: the pass-off verdict")
        opening = [b for t in targets for b in verdict_blocks(model[t], runs, schedule, t, alarms.verdicts)]
        if opening:
            panels.insert(0, Panel(VERDICT[0], VERDICT[1], opening, fold=False))
    for (pid, title), make in zip(PANELS, makers):
        log.info("report: %s", title)
        blocks: list[Block] = []
        for t in targets:
            if len(targets) > 1:
                blocks.append(Heading(f"target {t}"))
            blocks += make(t)
            step()
        panels.append(Panel(pid, title, blocks, GISTS[pid]))
    meta = [
        ("model", f"{model_name} ({model.bundles[0].method}; targets {', '.join(model.targets)})"),
        ("recordings", ", ".join(recordings)),
        ("runs", f"{len(runs.runs)}: {', '.join(runs.labels)}"),
        ("schedule", f"{len(schedule.ocs)} OCs on {schedule.switch}: {', '.join(schedule.names)}"),
        ("targets shown", ", ".join(targets)),
        ("made by", f"ordervib {__version__}"),
    ]
    page = render_document(f"ordervib report: {', '.join(targets)}", panels, meta)
    log.info("report: %d panels in %.1f s (%.1f MB)", len(panels), time.perf_counter() - t0,
             len(page) / 1e6)
    return page
