"""The pass-off verdict's forecast on held-out simulated engines (``monitor/verdict``).

    python -m bench verdict [--set report|dev|all] [--engines N] [--workdir DIR]
                            [--bands 3] [--quantile 0.85] [--after 3]

Each engine of the set (``bench.generalise``'s: its own seed, schedule and noise; the defaults of
the forecast were chosen on none of the ``report`` set) is simulated, nB and yB only: 18 runs, the
first 8 for training, the other 10 held out. Limits on yB are set from the training runs alone:
the plateau speeds cut into ``--bands`` speed bands of the switch channel, each limit the
``--quantile`` of the training runs' peaks in its band. The node's pipeline (``MonitorPipeline``,
a bundle of no OC model: the verdict needs none) with those limits and the training runs' peaks
(``node.training.forecast``) is stepped over each held-out run; the verdict made at the end of
plateau ``--after`` (the switch out of it) is scored against what then happened:

* per remaining segment with a limit, ``p_exceed`` against whether a sample there was over its
  limit: the Brier score beside climatology's (the training runs' exceedance frequency in that
  segment), and its skill 1 - Brier / climatology's;
* per run, ``p_fail`` against whether the rest of the run broke a limit, likewise;
* the predicted peaks' 90 % intervals: the share of the measured peaks inside.

Printed per engine and pooled, with the share of held-out runs that broke a limit somewhere and
a reliability table of the pooled ``p_exceed``. Recordings are kept in ``--workdir`` and reused.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.generalise import SCHEDULE_FILES, SETS, Engine
from harness import make

TRAIN_RUNS, HELD_OUT = 8, 10
TARGET, SWITCH = "yB", "nB"
BINS = (0.0, 0.1, 0.3, 0.7, 0.9, 1.0000001)
QUANTILE = 0.85  # the limits' quantile of the training runs' band peaks (0.7: over half the runs exceed)


@dataclass
class Scores:
    """What one engine's (or the pooled) forecasts scored: pairs of (forecast, outcome)."""

    p_exceed: list[tuple[float, float, float]] = field(default_factory=list)  # (p, climatology, hit)
    p_fail: list[tuple[float, float, float]] = field(default_factory=list)
    covered: list[bool] = field(default_factory=list)
    runs: int = 0
    failed: int = 0  # held-out runs over a limit somewhere

    def add(self, other: Scores) -> None:
        self.p_exceed += other.p_exceed
        self.p_fail += other.p_fail
        self.covered += other.covered
        self.runs += other.runs
        self.failed += other.failed

    @staticmethod
    def brier(pairs: list[tuple[float, float, float]]) -> tuple[float, float]:
        """(Brier of the forecasts, Brier of climatology) over pairs."""
        if not pairs:
            return math.nan, math.nan
        a = np.array(pairs)
        return float(np.mean((a[:, 0] - a[:, 2]) ** 2)), float(np.mean((a[:, 1] - a[:, 2]) ** 2))

    def row(self, name: str) -> str:
        be, ce = self.brier(self.p_exceed)
        bf, cf = self.brier(self.p_fail)
        cov = float(np.mean(self.covered)) if self.covered else math.nan
        return (f"| {name} | {self.runs} | {self.failed} | {len(self.p_exceed)} | {be:.3f} | {ce:.3f} | "
                f"{be / ce if ce > 0 else math.nan:.2f} | {bf:.3f} | {cf:.3f} | "
                f"{bf / cf if cf > 0 else math.nan:.2f} | {100 * cov:.0f} % ({len(self.covered)}) |")


def simulate(e: Engine, work: Path) -> Path:
    """The engine's 18 runs of nB and yB (reused when there)."""
    rec = work / f"{e.name}-verdict.mcap"
    if not rec.exists():
        file = SCHEDULE_FILES[e.schedule]
        make.simulate(rec, runs=TRAIN_RUNS + HELD_OUT, seed=e.seed, noise_scale=e.noise,
                      schedule=str(file) if file else None, channels=f"{SWITCH},{TARGET}", phase=False)
    return rec


def band_limits(train: list, schedule, bands: int, quantile: float) -> tuple:  # noqa: ANN001
    """The limits on the target: the plateau speeds in ``bands`` groups, each band from the middle
    between its group and the one below (0 for the first) to the middle above (open for the last),
    its limit the ``quantile`` of the training runs' peaks in the band."""
    from node.contract.schedule import Limit, Schedule
    from node.training.forecast import peak_table

    speeds = sorted(oc.speed for oc in schedule.ocs)
    groups = [list(g) for g in np.array_split(np.array(speeds), bands) if len(g)]
    edges = [None] + [0.5 * (float(a[-1]) + float(b[0])) for a, b in zip(groups, groups[1:])] + [None]
    limits = []
    for lo, hi in zip(edges, edges[1:]):
        probe = Schedule(schedule.ocs, schedule.switch, schedule.tolerance, (Limit(TARGET, 1.0, lo, hi),))
        band = peak_table(train, probe, TARGET).ratio  # (runs, segments): the peaks within the band
        peaks = np.max(np.where(np.isfinite(band), band, -np.inf), axis=1)
        limits.append(Limit(TARGET, float(np.quantile(peaks[peaks > -np.inf], quantile)), lo, hi))
    return tuple(limits)


def score_engine(rec: Path, bands: int, quantile: float, after: int) -> tuple[Scores, str]:
    """The engine's scores, and a line on its limits."""
    from node.contract.schedule import Schedule, load_schedule
    from node.models.bundle import Bundle
    from node.runtime.align import AlignedSample
    from node.runtime.pipeline import MonitorPipeline
    from node.training.forecast import peak_table
    from node.training.runs import read_runs

    runs = read_runs(rec, channels=[SWITCH, TARGET])
    train, held = runs[:TRAIN_RUNS], runs[TRAIN_RUNS:]
    plain = load_schedule(rec.with_suffix(".schedule.toml"))
    schedule = Schedule(plain.ocs, plain.switch, plain.tolerance, band_limits(train, plain, bands, quantile))
    table = peak_table(train, schedule, TARGET)
    bundle = Bundle("wdmd", TARGET, schedule, [], forecast=table)
    segs = schedule.segments
    climate = np.mean(table.ratio > 1.0, axis=0)  # (segments,) the training runs' frequency
    rest = np.mean(np.any(table.ratio[:, after:] > 1.0, axis=1))
    out = Scores()
    for run in held:
        pipe = MonitorPipeline(bundle)
        msgs, verdicts = [], []
        cols = [run.channels.index(c) for c in (SWITCH, TARGET)]
        for k, (t, row) in enumerate(zip(run.t.tolist(), run.data[:, cols].tolist())):
            msgs.append(pipe.step(AlignedSample(t, dict(zip((SWITCH, TARGET), row)), k == 0))[0])
            verdicts += pipe.verdicts
        peak = dict.fromkeys(segs, -math.inf)
        over = dict.fromkeys(segs, False)
        for m in msgs:
            if m["oc"] is not None and m["measured"] is not None:
                peak[m["oc"]] = max(peak[m["oc"]], m["measured"])
                over[m["oc"]] = over[m["oc"]] or m["over_limit"]
        out.runs += 1
        out.failed += any(over.values())
        at = next((v for v in verdicts if v["forecast"] and v["forecast"][0]["oc"] == segs[after]), None)
        if at is None:  # the run never left plateau ``after`` for the next segment
            continue
        for f in at["forecast"]:
            s = segs.index(f["oc"])
            if f["p_exceed"] is not None:
                out.p_exceed.append((f["p_exceed"], float(climate[s]), float(over[f["oc"]])))
            if f["peak"] is not None and peak[f["oc"]] > -math.inf:
                out.covered.append(f["peak_lo"] <= peak[f["oc"]] <= f["peak_hi"])
        later = any(over[s] for s in segs[after:])
        out.p_fail.append((at["p_fail"], float(rest), float(later)))
    words = ", ".join(f"{lim.where()} rpm: {lim.max:.2f}" for lim in schedule.limits)
    return out, words


def reliability(pairs: list[tuple[float, float, float]]) -> list[str]:
    """The pooled forecasts in bins of probability: how many, their mean, how often it happened."""
    a = np.array(pairs) if pairs else np.zeros((0, 3))
    lines = ["| p_exceed | forecasts | mean p | observed |", "| --- | --- | --- | --- |"]
    for lo, hi in zip(BINS, BINS[1:]):
        sel = (a[:, 0] >= lo) & (a[:, 0] < hi)
        if sel.any():
            lines.append(f"| {lo:.1f}-{min(hi, 1.0):.1f} | {int(sel.sum())} | {a[sel, 0].mean():.2f} | "
                         f"{a[sel, 2].mean():.2f} |")
    return lines


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m bench verdict", description=__doc__.split("\n\n")[0])
    p.add_argument("--set", choices=[*SETS, "all"], default="report")
    p.add_argument("--engines", type=int, default=None, help="the first N engines of the set")
    p.add_argument("--workdir", default=None, help="keep (and reuse) the recordings here")
    p.add_argument("--bands", type=int, default=3, help="speed bands with a limit (default 3)")
    p.add_argument("--quantile", type=float, default=QUANTILE,
                   help=f"each limit: this quantile of the training runs' peaks in its band (default "
                        f"{QUANTILE}: about a third of the held-out runs then exceed one somewhere)")
    p.add_argument("--prior-runs", type=float, default=None,
                   help="the level model's weight in the forecast's covariance, in runs (default: the "
                        "product's, node.models.forecast.PRIOR_RUNS; for choosing it on the dev set)")
    p.add_argument("--after", type=int, default=3, help="score the forecast made at the end of this "
                                                         "plateau (default the third)")
    args = p.parse_args(argv)
    if args.prior_runs is not None:
        from node.models import forecast
        forecast.PRIOR_RUNS = args.prior_runs
    engines = [e for name, es in SETS.items() if args.set in (name, "all") for e in es][:args.engines]
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="verdict-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"# verdict forecasts at the end of plateau {args.after}: {len(engines)} engine(s) of set "
          f"{args.set}, {TRAIN_RUNS} training and {HELD_OUT} held-out runs each; {args.bands} speed "
          f"band(s), limits at the {args.quantile:g} quantile of the training runs' band peaks\n")
    print("| engine | held-out runs | over a limit | segment forecasts | Brier p_exceed | climatology | "
          "ratio | Brier p_fail | climatology | ratio | 90 % interval coverage (peaks) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    pooled = Scores()
    limits = []
    t0 = time.perf_counter()
    for e in engines:
        scores, words = score_engine(simulate(e, work), args.bands, args.quantile, args.after)
        print(scores.row(e.name), flush=True)
        limits.append(f"- {e.name}: {words}")
        pooled.add(scores)
    print(pooled.row("pooled"))
    print()
    print("\n".join(reliability(pooled.p_exceed)))
    print("\nLimits (yB, mm/s) per engine:")
    print("\n".join(limits))
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0
