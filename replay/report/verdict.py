"""The report's opening section when the model has acceptance limits: the pass-off verdict.

Per target: each run's verdict as the node gave it (``monitor/verdict``, replayed offline:
``replay.offline.node_alarms``): pass or fail, the smallest margin (limit minus measured, the
target's unit) and the segment where it fell, with the run's engine, bed and date (the
recording's ``ordervib`` metadata record, ``node.mcap.recorded_engine``; "unknown" where it has
none). Then the forecasts the node made at each OC switch against what then happened: per
forecast segment with a limit, the predicted peak with its 90 % interval and ``p_exceed``
beside the measured peak and whether it exceeded the limit (the run's peaks measured as training
measures them, ``node.training.forecast.peak_table``), their Brier score beside climatology's
(the training runs' exceedance frequency in that segment), and a reliability diagram: the
forecasts binned by ``p_exceed`` against how often the limit was exceeded.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import parse_monitor_key
from node.contract.schedule import Schedule
from node.models.bundle import Bundle
from replay.report.document import Block, Figure, Heading, Paragraph, Table
from replay.report.panels import RunSet, _locate

VERDICT = ("verdict", "Pass-off verdict")  # the section's id and title: first on the page
BINS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0)  # the reliability diagram's bins of p_exceed
MAX_FORECAST_ROWS = 80  # forecast rows listed; the rest counted (the diagram has them all)
UNKNOWN = "unknown"


@dataclass(frozen=True)
class RunVerdict:
    """One run's verdict messages on one target: the run's index in the report's ``RunSet``
    (None: none holds it), its label, engine, bed and date, and the messages in order."""

    run: int | None
    label: str
    engine: str
    bed: str
    date: str
    messages: tuple[dict, ...]

    @property
    def final(self) -> dict:
        """The verdict at the run's end (else the last one given: the run did not end)."""
        ends = [m for m in self.messages if m["status"] != "pending" and not m["forecast"]]
        return ends[-1] if ends else self.messages[-1]


@dataclass(frozen=True)
class ForecastOutcome:
    """One segment's forecast made at an OC switch, beside what then happened: measured peak
    (NaN: the run lacks the segment), exceeded (None: not known), climatology (NaN: none)."""

    run: str
    made_at: str
    oc: str
    peak: float
    lo: float
    hi: float
    p_exceed: float
    measured: float
    exceeded: bool | None
    climatology: float


def run_verdicts(verdicts: Sequence[tuple[str, dict]], runs: RunSet, target: str) -> list[RunVerdict]:
    """The verdict messages on ``target`` grouped by run (bed and start), in order, each placed in
    the report's runs by its bed and time."""
    groups: dict[tuple[str, float], list[dict]] = {}
    for key, msg in verdicts:
        if msg.get("target") == target:
            bed = (parse_monitor_key(key) or ("", ""))[0]
            groups.setdefault((bed, float(msg["run"])), []).append(msg)
    out = []
    for (bed, start), msgs in groups.items():
        i, _, _ = _locate(runs.runs, [], [], bed, start)
        meta = runs.engines[i] if i is not None and runs.engines is not None else {}
        label = runs.labels[i] if i is not None else f"{bed} at {start:.1f} s"
        out.append(RunVerdict(i, label, meta.get("engine") or UNKNOWN, meta.get("bed") or bed or UNKNOWN,
                              meta.get("date") or UNKNOWN, tuple(msgs)))
    return out


def _num(x: float | None, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if x is not None and math.isfinite(x) else "-"


def headline(target: str, verdicts: Sequence[RunVerdict]) -> str:
    """The target's verdict in a line: pass or fail (how many runs failed, with several), the
    smallest margin and where it fell.

    >>> one = RunVerdict(0, "r #1", "E7", "b1", UNKNOWN, ({"status": "fail", "forecast": [],
    ...                  "margin": -0.25, "margin_oc": "OC7"},))
    >>> headline("yB", [one])
    'yB: FAIL, smallest margin -0.250 mm/s in OC7 (engine E7, bed b1, date unknown)'
    >>> headline("yB", [one, RunVerdict(1, "r #2", "E7", "b1", UNKNOWN, ({"status": "pass",
    ...          "forecast": [], "margin": 1.5, "margin_oc": "OC3"},))])
    'yB: 1 of 2 runs FAIL, smallest margin -0.250 mm/s in OC7 (r #1)'
    """
    finals = [v.final for v in verdicts]
    worst = min(((f["margin"], f["margin_oc"], v.label) for f, v in zip(finals, verdicts)
                 if f["margin"] is not None), default=None)
    where = f", smallest margin {_num(worst[0])} mm/s in {worst[1] or 'no OC'}" if worst else ""
    if len(verdicts) == 1:
        v = verdicts[0]
        return (f"{target}: {finals[0]['status'].upper()}{where} (engine {v.engine}, bed {v.bed}, "
                f"date {v.date})")
    failed = sum(f["status"] == "fail" for f in finals)
    tail = f" ({worst[2]})" if worst else ""
    return f"{target}: {failed} of {len(verdicts)} runs FAIL{where}{tail}"


def outcomes(verdicts: Sequence[RunVerdict], runs: RunSet, schedule: Schedule, bundle: Bundle,
             target: str) -> list[ForecastOutcome]:
    """Every forecast segment with a limit, made at an OC switch of a run the report holds, beside
    that run's measured peak there and whether it was over its limit."""
    from node.training.forecast import peak_table

    held = sorted({v.run for v in verdicts if v.run is not None})
    if not held:
        return []
    table = peak_table([runs.runs[i] for i in held], schedule, target)
    row = {i: k for k, i in enumerate(held)}  # run index -> the table's row
    climate = np.full(len(schedule.segments), np.nan)
    if bundle.forecast is not None:
        r = bundle.forecast.ratio
        n = np.isfinite(r).sum(axis=0)
        climate = np.where(n > 0, np.where(np.isfinite(r), r > 1.0, False).sum(axis=0) / np.maximum(n, 1),
                           np.nan)
    out = []
    for v in verdicts:
        if v.run is None:
            continue
        k = row[v.run]
        for msg in (m for m in v.messages if m["forecast"]):
            made_at = msg["forecast"][0]["oc"]
            for f in (f for f in msg["forecast"] if f["p_exceed"] is not None):
                s = schedule.segments.index(f["oc"])
                ratio = float(table.ratio[k, s])
                lo, mid, hi = (float(f[key]) if f[key] is not None else math.nan
                               for key in ("peak_lo", "peak", "peak_hi"))
                out.append(ForecastOutcome(v.label, made_at, f["oc"], mid, lo, hi, float(f["p_exceed"]),
                                           float(table.peak[k, s]),
                                           bool(ratio > 1.0) if math.isfinite(ratio) else None,
                                           float(climate[s])))
    return out


def reliability(p: np.ndarray, hit: np.ndarray, edges: Sequence[float] = BINS
                ) -> list[tuple[float, float, int, float, float]]:
    """The forecasts ``p`` (n,) against the outcomes ``hit`` (n,) in bins of p (``edges``, the
    last closed): per bin with any, (low edge, high edge, count, mean p, observed frequency).

    >>> reliability(np.array([0.05, 0.05, 0.95]), np.array([0.0, 1.0, 1.0]), (0.0, 0.5, 1.0))
    [(0.0, 0.5, 2, 0.05, 0.5), (0.5, 1.0, 1, 0.95, 1.0)]
    """
    out = []
    for k, (lo, hi) in enumerate(zip(edges, edges[1:])):
        sel = (p >= lo) & ((p < hi) if k < len(edges) - 2 else (p <= hi))
        if sel.any():
            out.append((float(lo), float(hi), int(sel.sum()), float(p[sel].mean()), float(hit[sel].mean())))
    return out


def reliability_figure(bins: Sequence[tuple[float, float, int, float, float]], target: str):  # noqa: ANN201
    """The reliability diagram: each bin's observed frequency against its mean p, its count
    written beside it; the diagonal is a forecast as often right as it says."""
    from matplotlib.figure import Figure as MplFigure

    from replay.views.style import LABEL, SMALL

    fig = MplFigure(figsize=(5.2, 4.4))
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls="--", label="as often as forecast")
    x = [b[3] for b in bins]
    y = [b[4] for b in bins]
    ax.plot(x, y, "o-", color="tab:blue", label="forecasts")
    for b in bins:
        ax.annotate(f"n={b[2]}", (b[3], b[4]), textcoords="offset points", xytext=(6, -12), fontsize=SMALL)
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.05)
    ax.set_xlabel("forecast p_exceed (bin mean)", fontsize=LABEL)
    ax.set_ylabel("observed frequency", fontsize=LABEL)
    ax.set_title(f"{target}: reliability of the forecasts", fontsize=LABEL)
    ax.tick_params(labelsize=SMALL)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=SMALL, loc="upper left")
    fig.tight_layout()
    return fig


def _verdict_table(verdicts: Sequence[RunVerdict], target: str) -> Table:
    rows, marks = [], []
    for v in verdicts:
        f = v.final
        status = f["status"] if f["forecast"] == [] else f"{f['status']} (the run did not end)"
        rows.append([v.label, v.engine, v.bed, v.date, status, _num(f["margin"]), f["margin_oc"] or "-",
                     _num(f["margin_speed"], 0)])
        marks.append(["", "", "", "", f["status"] if f["status"] in ("pass", "fail") else "", "", "", ""])
    return Table(["run", "engine", "bed", "date", "verdict", "smallest margin (mm/s)", "where", "at (rpm)"],
                 rows, f"{target}: each run's verdict (the node's monitor/verdict at the run's end); margin: "
                 "the limit minus the measured value, smallest over the run", marks=marks)


def _forecast_blocks(found: Sequence[ForecastOutcome], target: str) -> list[Block]:
    scored = [o for o in found if o.exceeded is not None]
    if not scored:
        return [Paragraph(f"{target}: no forecast of a limited segment to set against what happened "
                          "(the model keeps no training peaks, or no run went on after its first OC)",
                          note=True)]
    p = np.array([o.p_exceed for o in scored])
    hit = np.array([float(bool(o.exceeded)) for o in scored])
    brier = float(np.mean((p - hit) ** 2))
    clim = np.array([o.climatology for o in scored])
    ok = np.isfinite(clim)
    words = (f"Brier score {brier:.3f} over {len(scored)} forecasts"
             + (f", climatology's (the training runs' exceedance frequency per segment) "
                f"{float(np.mean((clim[ok] - hit[ok]) ** 2)):.3f}" if ok.all() else "")
             + f"; {int(hit.sum())} exceeded.")
    inside = [o.lo <= o.measured <= o.hi for o in scored if math.isfinite(o.lo) and math.isfinite(o.measured)]
    if inside:
        words += f" The 90 % intervals hold {100.0 * np.mean(inside):.0f} % of the measured peaks."
    bins = reliability(p, hit)
    rows, marks = [], []
    for o in found[:MAX_FORECAST_ROWS]:
        rows.append([o.run, o.made_at, o.oc, f"{_num(o.peak)} [{_num(o.lo)}, {_num(o.hi)}]",
                     f"{o.p_exceed:.2f}",
                     _num(o.measured), "-" if o.exceeded is None else "yes" if o.exceeded else "no"])
        marks.append(["", "", "", "", "", "", "worse" if o.exceeded else ""])
    more = f" (the first {MAX_FORECAST_ROWS} of {len(found)})" if len(found) > MAX_FORECAST_ROWS else ""
    return [
        Heading(f"{target}: the forecasts at each OC switch against what then happened", 4),
        Paragraph(f"At each OC switch the node forecast each remaining segment's peak with its 90 % interval "
                  f"and the probability that it exceeds its limit (p_exceed). {words}"),
        Figure.of(reliability_figure(bins, target), f"{target}: the forecasts binned by p_exceed (bins "
                  + ", ".join(f"{lo:g}-{hi:g}" for lo, hi in zip(BINS, BINS[1:]))
                  + ") against how often the limit was exceeded; n: forecasts in the bin"),
        Table(["p_exceed", "forecasts", "mean p", "observed"],
              [[f"{lo:g}-{hi:g}", str(n), f"{m:.2f}", f"{obs:.2f}"] for lo, hi, n, m, obs in bins],
              f"{target}: reliability of p_exceed"),
        Table(["run", "made at the switch into", "segment", "predicted peak [90 %] (mm/s)", "p_exceed",
               "measured peak (mm/s)", "exceeded"], rows,
              f"{target}: each forecast of a limited segment against the run{more}", marks=marks),
    ]


def verdict_blocks(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str,
                   verdicts: Sequence[tuple[str, dict]]) -> list[Block]:
    """One target's part of the verdict section (empty: the target has no limit)."""
    limits = schedule.limits_of(target)
    if not limits:
        return []
    rule = "; ".join(f"{lim.where()}{' rpm' if lim.oc is None and lim.where() != 'everywhere' else ''}: "
                     f"{lim.max:g} mm/s" for lim in limits)
    mine = run_verdicts(verdicts, runs, target)
    if not mine:
        return [Heading(f"{target}: no verdict"),
                Paragraph(f"Limits: {rule}. No run reached a segment of the schedule: the node gave no "
                          "verdict.", note=True)]
    return [Heading(headline(target, mine)),
            Paragraph(f"Limits on {target}: {rule} (the schedule's [[limit]] tables)."),
            _verdict_table(mine, target),
            *_forecast_blocks(outcomes(mine, runs, schedule, bundle, target), target)]
