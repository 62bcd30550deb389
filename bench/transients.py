"""Critical speeds and amplification factors read from ramps, against the simulator's own modes
(the targets: each critical within 1 %, each AF within 20 %).

    python -m bench transients [--seeds 1,2,3,4,5] [--runs 2] [--plateau-scale 1]
        [--noise-scale 1] [--tracker drawn|fixed] [--lag estimated|truth] [--schedule ramps|passoff]
        [--workdir W] [--rows all|fail|none]

Per engine (one simulator seed: its own modes, scattered about the nominal ones): ``--runs``
runs of a schedule made for ramps (idle, 6500, 9800, 6500 rpm of nB, then the decel to idle and
the rundown; ``--schedule passoff``: the simulator's pass-off test, 12 OCs whose ramps between
plateaus span 400-900 rpm, some ending on a critical), recorded by the simulator
(``harness.make.simulate``) and read back (``read_runs``). The ramps are found on nB
(``find_transitions``); per ramp and target (yA on nA, yB on nB, yC on nC: each order on its own
shaft's speed, the speed its truth is in) the node's ``node.runtime.transient.analyse`` with the
tracker's lag the node estimates from the engine's own runs
(``node.training.transients.tracker_lag``, as ``train`` does: the lag is not given; ``--lag
truth`` passes the truth JSON's instead), the amplitude and the phase as recorded (noise,
dropouts, quantisation). ``--tracker drawn`` (default): each engine's tracker lags by its own
time constant, 0.5-2 s (``simulate --tracker drawn``); the estimate is printed beside it.

The truth: every crossing of a critical the simulator made (``criticals`` of each run: the
mode's critical at the metal temperature of that moment, its damping, the steady 1x amplitude
there). Counted are the crossings inside a ramp whose half-power band (critical x (1 +- 1.5
zeta)) the ramp covers and whose amplitude at the critical is 1 mm/s or more (a run whose
imbalance happens to be small shows no resonance above the noise). Each is
matched to the critical found nearest in speed (within 3 zeta of it); the critical's error
in %, the AF's (API 684's half-power, of the fitted mode's own response) against the half-power
truth (the half-power AF of the simulated mode's own unbalance response, ``af_of_zeta``), the
phase fit's against 1 / (2 zeta), and beside them the half-power AF of the measured peak with the other
modes removed (``af_hp``, where it is clean). Beside them, in
the same run: the error of the raw amplitude peak without the tracker-lag correction, the
first-order figure for the lag (run-ups high, coast-downs low). Unmatched truth crossings are
misses, found criticals with no truth crossing near are spurious.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import tempfile
from pathlib import Path

import numpy as np

from harness import make
from node.console.table import print_table
from node.contract.schedule import load_schedule
from node.runtime.transient import Critical, af_of_zeta, analyse, find_transitions
from node.training.runs import Run, read_runs
from node.training.transients import tracker_lag

log = logging.getLogger(__name__)

CRITICAL_TARGET = 1.0  # %, |found - truth| / truth
MIN_RESONANCE = 1.0  # mm/s: crossings whose steady 1x amplitude at the critical is lower are not counted
AF_TARGET = 20.0  # %
TARGETS = (("yA", "nA"), ("yB", "nB"), ("yC", "nC"))
SCHEDULE = """# bench transients: ramps through the simulated engine's criticals
switch = "nB"
tolerance = 0.02

[[oc]]
name = "R1"
speed = 6500.0
plateau = 40
rate = 90

[[oc]]
name = "R2"
speed = 9800.0
plateau = 40
rate = 80

[[oc]]
name = "R3"
speed = 6500.0
plateau = 30
rate = 100
"""


def _pct(a: float | None, b: float) -> float | None:
    return None if a is None else 100.0 * (a - b) / b


def _cell(x: float | None, fmt: str = "{:+.2f}") -> str:
    return "-" if x is None else fmt.format(x)


def _covered(crossing: dict, lo: float, hi: float) -> bool:
    """Whether a ramp over shaft speeds lo..hi covers the crossing's half-power band (with
    some margin) and the resonance stands out (MIN_RESONANCE at the critical)."""
    half = 1.5 * crossing["zeta"] * crossing["speed"]
    return (lo <= crossing["speed"] - half and crossing["speed"] + half <= hi
            and crossing.get("amplitude", 0.0) >= MIN_RESONANCE)


def engine_rows(seed: int, work: Path, runs: int, plateau_scale: float, noise_scale: float,
                tracker: str = "drawn", lag: str = "estimated", schedule: str = "ramps"
                ) -> tuple[list[dict], dict]:
    """Simulate (unless present), read and analyse one engine; one dict per truth crossing
    counted or critical found, and the engine's lag (estimate, truth, crossings). schedule:
    "ramps" (``SCHEDULE``) or "passoff" (the simulator's built-in pass-off test)."""
    rec = work / f"engine{seed}.{tracker}.{schedule}.mcap"
    if schedule == "ramps":
        sched = work / "transients.schedule.toml"
        if not sched.exists():
            sched.write_text(SCHEDULE)
    else:
        sched = rec.with_suffix(".schedule.toml")  # the simulator writes its own
    truth_path = rec.with_suffix(".truth.json")
    truth = json.loads(truth_path.read_text()) if rec.exists() and truth_path.exists() else None
    if (truth is None or "rotor" not in truth or len(truth["runs"]) != runs
            or truth.get("noise_scale") != noise_scale):
        log.info("simulating engine %d", seed)
        truth = make.simulate(rec, runs=runs, seed=seed, schedule=str(sched) if schedule == "ramps" else None,
                              plateau_scale=plateau_scale, noise_scale=noise_scale, tracker=tracker)
    recorded = read_runs(rec)
    true_tau = float(truth["rotor"]["tracker_s"])  # scoring only (and --lag truth)
    est, fits = tracker_lag(recorded, load_schedule(str(sched)), [t for t, _ in TARGETS])
    tau = true_tau if lag == "truth" else (est.tau if est is not None else 0.0)
    lag_row = {"engine": seed, "truth": true_tau, "estimate": None if est is None else est.tau,
               "spread": None if est is None else est.spread,
               "crossings": 0 if est is None else est.crossings, "fitted": len(fits), "used": tau}
    out: list[dict] = []
    for r, (run, tr) in enumerate(zip(recorded, truth["runs"], strict=True)):
        for span in find_transitions(run.column("nB")):
            part = slice(span.start, span.stop)
            t0, t1 = float(run.t[span.start]), float(run.t[span.stop - 1])
            for target, speed_ch in TARGETS:
                out.extend(_ramp_rows(seed, r, run, part, span.direction, target, speed_ch, tau,
                                      [c for c in tr["criticals"][target] if t0 <= c["t"] <= t1]))
    return out, lag_row


def _ramp_rows(seed: int, r: int, run: Run, part: slice, direction: str, target: str,
               speed_ch: str, tau: float, truth: list[dict]) -> list[dict]:
    speed = run.column(speed_ch)[part]
    amp = run.column(target)[part]
    ph_name = target + "_ph"
    phase = run.column(ph_name)[part] if ph_name in run.channels else None
    found = analyse(speed, amp, phase, tracker_tau=tau, min_amplitude=0.2).criticals
    raw = analyse(speed, amp, phase, tracker_tau=0.0, min_amplitude=0.2).criticals
    lo, hi = float(np.nanmin(speed)), float(np.nanmax(speed))
    base = {"engine": seed, "run": r, "dir": direction, "target": target,
            "ramp": f"{run.column('nB')[part][0]:.0f}->{run.column('nB')[part][-1]:.0f}"}
    rows = []
    used: set[int] = set()
    counted = [c for c in truth if _covered(c, lo, hi)]
    # each found critical answers one truth crossing: nearest pairs first
    pairs = sorted((abs(f.speed - c["speed"]), j, i) for j, c in enumerate(counted)
                   for i, f in enumerate(found) if abs(f.speed - c["speed"]) <= 3 * c["zeta"] * c["speed"])
    match: dict[int, int] = {}
    for _, j, i in pairs:
        if j not in match and i not in used:
            match[j] = i
            used.add(i)
    for j, c in enumerate(counted):
        hit: Critical | None = found[match[j]] if j in match else None
        unc = [x for x in raw if abs(x.speed_peak - c["speed"]) <= 3 * c["zeta"] * c["speed"]]
        af_truth = af_of_zeta(c["zeta"])  # the half-power AF of the mode's own response
        rows.append({**base, "mode": c["mode"], "truth": c["speed"], "rate": c["rate_rpm_s"],
                     "af_truth": af_truth, "found": hit,
                     "err": _pct(hit.speed, c["speed"]) if hit else None,
                     "err_hp": _pct(hit.speed_hp, c["speed"]) if hit else None,
                     "af_method": hit.af_method if hit else "-",
                     "err_raw_peak": _pct(unc[0].speed_peak, c["speed"]) if unc else None,
                     "err_af": _pct(hit.af, af_truth) if hit else None,
                     "err_af_phase": _pct(hit.af_phase, c["af"]) if hit else None,
                     "err_af_hp": _pct(hit.af_hp, c["af"]) if hit else None})
    for i, f in enumerate(found):
        if i not in used and not any(abs(f.speed - c["speed"]) <= 3 * c["zeta"] * c["speed"]
                                     for c in truth):
            rows.append({**base, "mode": None, "truth": None, "found": f, "spurious": True})
    return rows


def _passes(row: dict) -> bool:
    return (row["found"] is not None and row["err"] is not None and abs(row["err"]) <= CRITICAL_TARGET
            and row["err_af"] is not None and abs(row["err_af"]) <= AF_TARGET)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench transients", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3,4,5", help="simulated engines (default 1,2,3,4,5)")
    ap.add_argument("--runs", type=int, default=2, help="runs per engine (default 2)")
    ap.add_argument("--plateau-scale", type=float, default=1.0, help="simulate --plateau-scale (default 1)")
    ap.add_argument("--noise-scale", type=float, default=1.0, help="simulate --noise-scale (default 1, > 0)")
    ap.add_argument("--tracker", choices=("drawn", "fixed"), default="drawn",
                    help="the simulated order tracker's lag: drawn per engine in 0.5-2 s (default) or 1 s")
    ap.add_argument("--lag", choices=("estimated", "truth"), default="estimated",
                    help="the lag undone: estimated from the engine's runs (default) or the truth's")
    ap.add_argument("--schedule", choices=("ramps", "passoff"), default="ramps",
                    help="ramps made for the criticals (default) or the simulator's pass-off test (12 OCs, "
                         "ramps between plateaus of a few hundred rpm)")
    ap.add_argument("--workdir", help="keep the recordings here (default: a new temp folder)")
    ap.add_argument("--rows", choices=("all", "fail", "none"), default="all",
                    help="which crossings to list (default all)")
    args = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds must be integers separated by commas, got {args.seeds!r}")
    if not seeds or min(seeds) < 0 or not 1 <= args.runs <= 10:
        ap.error("--seeds must be >= 0 and --runs between 1 and 10")
    if not (math.isfinite(args.noise_scale) and args.noise_scale > 0
            and 0.05 <= args.plateau_scale <= 10.0):
        ap.error("--noise-scale must be > 0 and finite, --plateau-scale between 0.05 and 10")
    if args.workdir is not None and not Path(args.workdir).is_dir():
        ap.error(f"--workdir {args.workdir} is not a folder")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir or tmp)
        per = [engine_rows(s, work, args.runs, args.plateau_scale, args.noise_scale, args.tracker,
                           args.lag, args.schedule) for s in seeds]
    rows = [row for r, _ in per for row in r]
    lags = [lag for _, lag in per]
    counted = [r for r in rows if not r.get("spurious")]
    spurious = [r for r in rows if r.get("spurious")]
    shown = {"all": counted, "fail": [r for r in counted if not _passes(r)], "none": []}[args.rows]
    if args.rows != "none" and spurious:
        print_table(["engine", "run", "ramp nB", "dir", "target", "found rpm", "AF", "AF by", "amplitude"],
                    [[str(r["engine"]), str(r["run"]), r["ramp"], r["dir"], r["target"],
                      f"{r['found'].speed:.0f}", f"{r['found'].af:.1f}", r["found"].af_method,
                      f"{r['found'].amplitude:.2f}"] for r in spurious],
                    title="criticals found where the simulator has none")
    if shown:
        print_table(
            ["engine", "run", "ramp nB", "dir", "target", "mode", "truth rpm", "rate rpm/s", "found rpm",
             "err %", "hp err %", "raw peak err %", "AF truth", "AF", "AF by", "AF err %", "AF phase err %",
             "result"],
            [[str(r["engine"]), str(r["run"]), r["ramp"], r["dir"], r["target"], str(r["mode"]),
              f"{r['truth']:.0f}", f"{r['rate']:+.0f}",
              _cell(r["found"].speed if r["found"] else None, "{:.0f}"), _cell(r["err"]),
              _cell(r["err_hp"]), _cell(r["err_raw_peak"]), f"{r['af_truth']:.1f}",
              _cell(r["found"].af if r["found"] else None, "{:.1f}"), r["af_method"],
              _cell(r["err_af"], "{:+.1f}"),
              _cell(r["err_af_phase"], "{:+.1f}"), "PASS" if _passes(r) else "FAIL"]
             for r in shown],
            title="crossings of the simulator's criticals (err: found - truth, % of truth)")
    print_engines(counted, spurious, lags)
    print_summary(counted, spurious, len(seeds))
    lag_ok = all(x["estimate"] is not None
                 and abs(x["estimate"] - x["truth"]) <= LAG_TARGET / 100 * x["truth"]
                 for x in lags)
    return 0 if counted and all(_passes(r) for r in counted) and lag_ok else 1


LAG_TARGET = 20.0  # %: the lag estimate against the simulator's


def print_engines(counted: list[dict], spurious: list[dict], lags: list[dict]) -> None:
    """Per engine: crossings found of those counted, the worst critical and AF errors, the
    spurious criticals, the lag estimated beside the truth."""
    rows = []
    for lag in lags:
        e = lag["engine"]
        mine = [r for r in counted if r["engine"] == e]
        found = [r for r in mine if r["found"] is not None]
        worst = max((abs(r["err"]) for r in found), default=math.nan)
        worst_af = max((abs(r["err_af"]) for r in found if r["err_af"] is not None), default=math.nan)
        est = lag["estimate"]
        rows.append([str(e), f"{len(found)} / {len(mine)}", f"{worst:.2f}", f"{worst_af:.1f}",
                     str(sum(1 for r in spurious if r["engine"] == e)),
                     "-" if est is None else f"{est:.2f} +- {lag['spread']:.2f}", f"{lag['truth']:.2f}",
                     "-" if est is None else f"{100 * (est - lag['truth']) / lag['truth']:+.1f}",
                     f"{lag['crossings']} / {lag['fitted']}", f"{lag['used']:.2f}"])
    print_table(["engine", "crossings found", "max |crit err| %", "max |AF err| %", "spurious",
                 "lag estimated s", "lag truth s", "lag err %", "lag crossings (pinned / fitted)",
                 "lag undone s"], rows,
                title=f"per engine (targets: critical within {CRITICAL_TARGET:g} %, AF within "
                      f"{AF_TARGET:g} % of the half-power truth, lag within {LAG_TARGET:g} %)")


def _stat(values: list[float | None]) -> str:
    v = np.abs([x for x in values if x is not None])
    return "-" if not len(v) else f"median {np.median(v):.2f}, max {np.max(v):.2f}"


def _mean(rows: list[dict], key: str) -> float:
    v = [r[key] for r in rows if r[key] is not None]
    return float(np.mean(v)) if v else float("nan")


def print_summary(counted: list[dict], spurious: list[dict], engines: int) -> None:
    """The figures against the targets, and the comparison without the tracker-lag correction."""
    found = [r for r in counted if r["found"] is not None]
    crit_ok = sum(1 for r in found if abs(r["err"]) <= CRITICAL_TARGET)
    af_ok = sum(1 for r in found if r["err_af"] is not None and abs(r["err_af"]) <= AF_TARGET)
    rows = [
        ["crossings counted", str(len(counted)), f"{engines} engines"],
        ["found", str(len(found)), f"missed {len(counted) - len(found)}, spurious {len(spurious)}"],
        [f"critical within {CRITICAL_TARGET:g} %", f"{crit_ok} / {len(counted)}",
         "|err| % " + _stat([r["err"] for r in found])],
        [f"AF within {AF_TARGET:g} %", f"{af_ok} / {len(counted)}",
         "|err| % " + _stat([r["err_af"] for r in found])],
        ["AF (phase fit) |err| %", "", _stat([r["err_af_phase"] for r in found])],
        *[[label, str(sum(1 for r in found if r["af_method"] == method)),
           "|err| % " + _stat([r["err_af"] for r in found if r["af_method"] == method])]
          for label, method in (("AF by the fitted mode's half-power", "modal fit"),
                                ("AF by half-power on the measured peak", "half-power"))],
        ["beside it: the measured isolated peak's (af_hp)",
         str(sum(1 for r in found if r["err_af_hp"] is not None)),
         "|err| % " + _stat([r["err_af_hp"] for r in found])],
        ["critical from half-power only |err| %", "", _stat([r["err_hp"] for r in found])],
        ["raw peak, no lag correction |err| %", "", _stat([r["err_raw_peak"] for r in counted])],
    ]
    for d in ("up", "down"):
        sel = [r for r in counted if r["dir"] == d]
        if sel:
            rows.append([f"mean signed err % ({d})", "", f"corrected {_mean(sel, 'err'):+.2f}, "
                         f"raw peak {_mean(sel, 'err_raw_peak'):+.2f}"])
    ok = bool(counted) and crit_ok == len(counted) and af_ok == len(counted)
    rows.append(["result", "PASS" if ok else "FAIL", ""])
    print_table(["figure", "value", "detail"], rows, title="summary")
