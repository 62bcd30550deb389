"""Predictions of planned runs within physics: the bound on random plans, and the
interval's coverage on held-out runs.

    python -m bench plans [--seed 3 | --seeds 3,4,5,6] [--train-runs 8] [--held-out 10]
        [--plans 20] [--plateau-scale 0.25] [--targets yA,yB] [--workdir W] [--workers 2]

On one simulated engine (the project's simulator, one seed, plateaus at ``--plateau-scale``):
its first ``--train-runs`` runs train a model with the defaults (``--targets``), the next
``--held-out`` runs are held out. Then, through ``node.training.prediction`` (the node's own
code, as ``ordervib predict`` runs it):

1. ``--plans`` random plans within the training speeds: 3-7 OCs in random order, each at its
   schedule speed moved by up to half the schedule's tolerance (within the training runs' nB
   range), held 8-40 s, ramps of 50-300 rpm/s, from and back to standstill; only t and nB, the
   other inputs filled from the training runs. Per target: the share of predicted samples
   within [0, 1.5 x the largest the training runs measured in the same OC within 100 rpm]
   (none there: of any OC within 100 rpm; none either: the OC's largest), computed here from
   the training runs by brute force, not by the product's bound (speeds in the rule's 5 rpm
   steps). Target: all of them. The
   node's own share before the bounds is printed beside it.
2. The held-out runs, each given its own profile (its recorded nB and channels, its targets
   left out; the engine history the training runs and the held-out runs before it leave): per
   target the share of measured samples inside the 90 % interval (target 85-95 %), beside the
   share inside the interval of the CV sigma alone (``IntervalWidths.from_cv``) and inside
   the rule before the run levels (symmetric, t sqrt(1 + 1/n) x the RMS chained residual);
   per OC the share inside and the training runs' run levels (shift, between, within).
3. The training runs' chained eps_td per OC with the mean modulus for 1x-vector models (the
   training runs' mean amplitude in the OC at the speed, ``levels``) against the node's own
   modulus of the mean vector (``mean_modulus=False``).

With ``--seeds`` every engine in turn (each in ``W/s<seed>``), then the held-out coverage pooled
over the engines' samples per target: the criterion's verdict (85-95 %). A held-out run's level is
its own, so a run falls inside its interval nearly all or nothing and one engine's ten runs say
little: beside each engine's share and the pooled one, the range a perfectly calibrated 90 %
interval gives (``calibrated_spread``: the exact Student-t interval of the run levels of
``--train-runs`` runs, judged on ``--held-out`` new runs, simulated), and how often it lands within
85-95 % for one engine and for the pool.

``--workdir`` keeps the recordings and the model: a later run with the same settings reuses
them. One engine takes about 2-6 minutes on 2 cores (most of it the training).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from harness import make
from node.contract.schedule import Schedule
from node.models.bundle import Model, load_model
from node.runtime.history import SLOW_TEMPERATURES
from node.training.dataset import segment_runs
from node.training.fit import load_runs
from node.training.prediction import (
    MEAN_MODULUS,
    Profile,
    history_after,
    needed_channels,
    predict_profile,
    predict_recorded_runs,
    recorded_eps,
    with_interval,
)
from node.training.prediction_aids import (
    BOUND_FACTOR,
    BOUND_STEP_RPM,
    BOUND_WINDOW_RPM,
    AmplitudeBound,
    InputFill,
    IntervalWidths,
)
from node.training.runs import Run

log = logging.getLogger("bench.plans")
COVERAGE = (0.85, 0.95)  # the target for the 90 % interval on held-out runs
SEEDS_MAX = 32  # engines in one run at most
SPREAD_ENGINES = 20_000  # simulated engines for calibrated_spread


@dataclasses.dataclass
class EngineResult:
    """One engine's figures: per target (K,), predicted samples of the plans within the bound
    and in all, held-out measured samples inside the interval and in all, each held-out run's
    share inside."""

    seed: int
    targets: tuple[str, ...]
    within: np.ndarray
    total: np.ndarray
    inside: np.ndarray
    measured: np.ndarray
    per_run: list[list[float]]


def calibrated_spread(n_train: int, n_held: int, engines: int, pooled: int = 1, level: float = 0.9,
                      seed: int = 0) -> tuple[float, float, float]:
    """The share of held-out runs inside a perfectly calibrated ``level`` interval, where a run's
    level is all its error (the all-or-nothing extreme): per simulated engine, ``n_train`` run
    levels give the exact Student-t prediction interval (mean -/+ t s sqrt(1 + 1/n)), ``n_held``
    new runs fall in or out; ``pooled`` engines' shares averaged. Returns the 5th and 95th
    percentiles of the (pooled) share over ``engines`` simulations and the fraction of them
    within ``COVERAGE``.

    >>> lo, hi, hit = calibrated_spread(8, 10, 4000)
    >>> lo < 0.75 and hi == 1.0 and 0.1 < hit < 0.5
    True
    """
    from scipy.stats import t as student

    rng = np.random.default_rng(seed)
    levels = rng.standard_normal((engines, pooled, n_train))
    new = rng.standard_normal((engines, pooled, n_held))
    factor = student.ppf(0.5 + level / 2.0, n_train - 1) * np.sqrt(1.0 + 1.0 / n_train)
    half = factor * levels.std(axis=2, ddof=1)
    share = (np.abs(new - levels.mean(axis=2, keepdims=True)) <= half[..., None]).mean(axis=(1, 2))
    lo, hi = np.percentile(share, [5, 95])
    within = (share >= COVERAGE[0] - 1e-12) & (share <= COVERAGE[1] + 1e-12)
    return float(lo), float(hi), float(np.mean(within))


def _recordings(work: Path, seed: int, n: int, m: int, scale: float) -> tuple[Path, Path]:
    """train.mcap (runs 1..n) and held.mcap (runs n+1..n+m) of one engine, reused when there."""
    train, held = work / "train.mcap", work / "held.mcap"
    for rec, runs, skip in ((train, n, 0), (held, n + m, n)):
        truth = rec.with_suffix(".truth.json")
        if rec.exists() and truth.exists():
            t = json.loads(truth.read_text())
            if len(t["runs"]) == runs - skip and t["seed"] == seed:
                continue
        make.simulate(rec, runs=runs, seed=seed, skip=skip, plateau_scale=scale)
    return train, held


def _model(work: Path, train: Path, targets: str, workers: int) -> Path:
    """The model of train.mcap (defaults, ``targets``), reused when the work dir holds it."""
    out = work / "model"
    stamp = work / "model.json"
    want = {"targets": targets, "train": train.stat().st_size}
    if (out / "manifest.json").exists() and stamp.exists() and json.loads(stamp.read_text()) == want:
        log.info("model: reused %s", out)
        return out
    make.train([train], train.with_suffix(".schedule.toml"), out, workers=workers, target=targets)
    stamp.write_text(json.dumps(want))
    return out


def random_plan(rng: np.random.Generator, schedule: Schedule, lo: float, hi: float) -> Profile:
    """A plan of t and nB (see the module): 3-7 OCs in random order within [lo, hi] rpm."""
    k = int(rng.integers(3, 8))
    order = rng.choice(len(schedule.ocs), size=min(k, len(schedule.ocs)), replace=False)
    t, v = [0.0, 5.0], [0.0, 0.0]
    for o in order:
        speed = schedule.ocs[int(o)].speed * (1.0 + rng.uniform(-0.5, 0.5) * schedule.tolerance)
        speed = float(np.clip(speed, lo, hi))
        ramp = rng.uniform(50.0, 300.0)
        t.append(t[-1] + abs(speed - v[-1]) / ramp)
        v.append(speed)
        t.append(t[-1] + rng.uniform(8.0, 40.0))
        v.append(speed)
    t += [t[-1] + v[-1] / rng.uniform(50.0, 300.0), 0.0]
    t[-1] = t[-2] + 5.0
    v += [0.0, 0.0]
    return Profile(np.array(t), np.array(v)[:, None], (schedule.switch,), schedule.switch)


class BruteBound:
    """The rule read off the training runs directly: per target and OC (as
    ``segment_runs`` cuts them), the samples sorted by speed (in the rule's 5 rpm steps); the
    largest within the window by a sparse table of maxima."""

    def __init__(self, runs: list[Run], schedule: Schedule, target: str) -> None:
        O = len(schedule.names)
        label = [np.full(len(r.t), O) for r in runs]
        for s in segment_runs(runs, schedule):
            label[s.run][s.start:s.stop] = s.oc
        speed = _steps(np.concatenate([r.column(schedule.switch) for r in runs]))
        y = np.concatenate([r.column(target) for r in runs])
        oc = np.concatenate(label)
        ok = np.isfinite(speed) & np.isfinite(y)
        self.tables = {o: self._table(speed[ok & (oc == o)], y[ok & (oc == o)]) for o in range(O)}
        self.tables[-1] = self._table(speed[ok], y[ok])
        self.top = {o: float(np.max(y[ok & (oc == o)])) if (ok & (oc == o)).any() else np.nan
                    for o in range(O)}
        self.all_top = float(np.max(y[ok]))

    @staticmethod
    def _table(speed: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        order = np.argsort(speed)
        levels = [y[order]]
        while 2 ** len(levels) <= len(order):
            prev, half = levels[-1], 2 ** (len(levels) - 1)
            levels.append(np.maximum(prev[:-half], prev[half:]))
        return speed[order], levels

    @staticmethod
    def _max(table: tuple[np.ndarray, list[np.ndarray]], q: np.ndarray, window: float) -> np.ndarray:
        speed, levels = table
        a = np.searchsorted(speed, q - window, "left")
        b = np.searchsorted(speed, q + window, "right")
        out = np.full(q.size, np.nan)
        has = b > a
        if has.any():
            n = b[has] - a[has]
            k = np.floor(np.log2(n)).astype(int)
            vals = np.empty(n.size)
            for lv in np.unique(k):
                sel = k == lv
                arr = levels[lv]
                vals[sel] = np.maximum(arr[a[has][sel]], arr[b[has][sel] - 2 ** lv])
            out[has] = vals
        return out

    def limit(self, oc: int, speed: np.ndarray) -> np.ndarray:
        """1.5 x the rule's largest (K,) at ``speed`` (K,) rpm in OC ``oc`` (-1: outside every OC)."""
        q = _steps(speed)
        window = BOUND_WINDOW_RPM + 1e-6  # inclusive
        mine = self._max(self.tables[oc], q, window)
        anyone = self._max(self.tables[-1], q, window)
        last = self.top.get(oc, np.nan)
        last = last if np.isfinite(last) else self.all_top
        return BOUND_FACTOR * np.where(np.isfinite(mine), mine, np.where(np.isfinite(anyone), anyone, last))


def _steps(speed: np.ndarray) -> np.ndarray:
    """Speeds (rpm) rounded to the rule's 5 rpm steps (NaN stays NaN)."""
    return np.round(np.asarray(speed, float) / BOUND_STEP_RPM) * BOUND_STEP_RPM


def _rms_rule(w: IntervalWidths) -> IntervalWidths:
    """The interval rule before the run levels (for comparison): symmetric about the prediction,
    t(n-1) sqrt(1 + 1/n) x the larger of the RMS chained residual and the CV sigma."""
    from scipy.stats import t as student

    n_runs = np.maximum(w.runs, 2)
    factor = student.ppf(0.5 + w.level / 2.0, n_runs - 1) * np.sqrt(1.0 + 1.0 / n_runs)
    half = np.where(w.runs >= 2, factor * np.fmax(w.chain_rms, w.cv_sigma), w.half)
    return dataclasses.replace(w, half=half, shift=np.zeros_like(half))


def _bounded(within: np.ndarray, total: np.ndarray) -> np.ndarray:
    """Per target: the plans predicted samples and every one lies within the bound."""
    return (total > 0) & (within == total)


def _covered(inside: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Per target: held-out samples were measured and the share inside the interval lies within
    ``COVERAGE``."""
    share = inside / np.maximum(measured, 1)
    return (measured > 0) & (share >= COVERAGE[0]) & (share <= COVERAGE[1])


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench plans")
    ap.add_argument("--seed", type=int, default=3, help="the simulated engine (default 3)")
    ap.add_argument("--seeds", default=None,
                    help="several engines (comma-separated seeds), the coverage pooled over them")
    ap.add_argument("--train-runs", type=int, default=8)
    ap.add_argument("--held-out", type=int, default=10,
                    help="held-out runs (default 10: a run is inside its interval nearly all or nothing, "
                         "its level being its own, so a share needs several)")
    ap.add_argument("--plans", type=int, default=20)
    ap.add_argument("--plateau-scale", type=float, default=0.25)
    ap.add_argument("--targets", default="yA,yB")
    ap.add_argument("--workdir", default=None, help="keep the recordings and the model here (reused)")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    try:
        seeds = [int(x) for x in args.seeds.split(",")] if args.seeds else [args.seed]
    except ValueError:
        ap.error(f"--seeds {args.seeds!r}: comma-separated integers")
    if not 1 <= len(seeds) <= SEEDS_MAX or len(set(seeds)) != len(seeds):
        ap.error(f"--seeds: 1 to {SEEDS_MAX} distinct engines")
    if not (2 <= args.train_runs <= 200 and 1 <= args.held_out <= 200 and 0 <= args.plans <= 1000):
        ap.error("--train-runs 2-200, --held-out 1-200, --plans 0-1000")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    work = Path(args.workdir or tempfile.mkdtemp(prefix="ordervib-plans-"))
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results = [engine(args, seed, work / f"s{seed}" if args.seeds else work) for seed in seeds]
    failed = not all(_bounded(r.within, r.total).all() for r in results)
    if args.seeds:
        failed |= not pooled(results, args.train_runs, args.held_out)
    else:
        failed |= not _covered(results[0].inside, results[0].measured).all()
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 1 if failed else 0


def pooled(results: list[EngineResult], n_train: int, n_held: int) -> bool:
    """Prints each engine's held-out coverage and the pool's per target, beside what a calibrated
    interval gives, and the plans' bound over every engine; True when every target's pooled share
    lies within ``COVERAGE``."""
    targets = results[0].targets
    one = calibrated_spread(n_train, n_held, SPREAD_ENGINES)
    pool = calibrated_spread(n_train, n_held, SPREAD_ENGINES // len(results), pooled=len(results))
    print(f"\n## Held-out samples inside the 90 % interval, {len(results)} engines "
          f"({n_train} training runs, {n_held} held out each)\n")
    print("| engine | " + " | ".join(targets) + " |")
    print("|---|" + "---|" * len(targets))
    for r in results:
        cover = r.inside / np.maximum(r.measured, 1)
        print(f"| seed {r.seed} | " + " | ".join(f"{c:.1%}" for c in cover) + " |")
    inside = np.sum([r.inside for r in results], axis=0)
    measured = np.sum([r.measured for r in results], axis=0)
    share = inside / np.maximum(measured, 1)
    ok = _covered(inside, measured)
    cells = (f"**{c:.1%}** {_verdict(bool(g))}" for c, g in zip(share, ok, strict=True))
    print("| **pooled** | " + " | ".join(cells) + " |")
    band = f"{COVERAGE[0]:.0%}-{COVERAGE[1]:.0%}"
    print(f"\nA perfectly calibrated interval, each run's level all its error (simulated): one engine's "
          f"share lies in {one[0]:.0%}-{one[1]:.0%} (5th-95th percentile), within {band} for {one[2]:.0%} "
          f"of engines; pooled over {len(results)} engines {pool[0]:.0%}-{pool[1]:.0%}, within for "
          f"{pool[2]:.0%}. The criterion is judged on the pool.")
    for j, tg in enumerate(targets):
        print(f"{_verdict(bool(ok[j]))}  {tg} held-out, pooled: {int(inside[j])} of {int(measured[j])} "
              f"measured samples ({share[j]:.1%}) inside the 90 % interval (target {band})")
    bounded = [_bounded(r.within, r.total) for r in results]
    for j, tg in enumerate(targets):  # the bound, every engine (each engine's lines above say which)
        w, n = sum(int(r.within[j]) for r in results), sum(int(r.total[j]) for r in results)
        bad = [r.seed for r, b in zip(results, bounded, strict=True) if not b[j]]
        print(f"{_verdict(not bad)}  {tg} plans, every engine: {w} of {n} predicted samples within the bound"
              + (f"; outside on seed(s) {', '.join(map(str, bad))}" if bad else ""))
    return bool(ok.all())


def engine(args: argparse.Namespace, seed: int, work: Path) -> EngineResult:
    """One engine's recordings, model, plans and held-out runs (see the module); prints its
    figures."""
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_rec, held_rec = _recordings(work, seed, args.train_runs, args.held_out, args.plateau_scale)
    log.info("recordings in %s (%.0f s)", work, time.perf_counter() - t0)
    model: Model = load_model(_model(work, train_rec, args.targets, args.workers))
    sched = model.schedule
    log.info("model of %s (%.0f s)", args.targets, time.perf_counter() - t0)
    train, held = load_runs([str(train_rec)], True), load_runs([str(held_rec)], True)
    t1 = time.perf_counter()
    bound = AmplitudeBound.fit(train, sched, model.targets)
    levels = InputFill.fit(train, sched, model.targets, "training runs")
    chained = predict_recorded_runs(model, train, bound=bound, levels=levels)
    widths = IntervalWidths.from_recorded(model, chained)
    node_own = predict_recorded_runs(model, train, bound=bound, mean_modulus=False)
    eps_mean, eps_node = recorded_eps(chained), recorded_eps(node_own)
    rms_rule = _rms_rule(widths)
    want = sorted({*needed_channels(model), *SLOW_TEMPERATURES} - {sched.switch})
    fill = InputFill.fit(train, sched, want, "training runs")
    engine = history_after(train, model)
    log.info("bound, interval and fill from %d training runs (%.0f s)", len(train), time.perf_counter() - t1)
    speeds = np.concatenate([r.column(sched.switch) for r in train])
    on = speeds[speeds > 0.5 * min(oc.speed for oc in sched.ocs)]
    lo, hi = float(np.nanmin(on)), float(np.nanmax(on))
    brute = {tg: BruteBound(train, sched, tg) for tg in model.targets}

    # 1. random plans: within [0, the rule's bound]
    rng = np.random.default_rng(seed)
    n = len(model.targets)
    within, raw_within, total, acted = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    mean_mod = np.zeros(n)
    t1 = time.perf_counter()
    samples = 0
    for _ in range(args.plans):
        p = predict_profile(model, random_plan(rng, sched, lo, hi), engine, fill, bound=bound, widths=widths,
                            levels=levels)
        samples += p.t.size
        for j, tg in enumerate(model.targets):
            y, raw = p.predicted[:, j], p.raw[:, j]
            ok = np.isfinite(y) & (p.oc >= 0)
            cap = np.full(y.size, np.nan)
            for o in np.unique(p.oc[ok]):
                mine = ok & (p.oc == o)
                cap[mine] = brute[tg].limit(int(o), p.speed[mine])
            within[j] += np.sum((y[ok] >= 0) & (y[ok] <= cap[ok] + 1e-9))
            raw_within[j] += np.sum((raw[ok] >= 0) & (raw[ok] <= cap[ok] + 1e-9))
            total[j] += ok.sum()
            acted[j] += np.sum((p.bounded[ok, j] != 0) & (p.bounded[ok, j] != MEAN_MODULUS))
            mean_mod[j] += np.sum(p.bounded[ok, j] == MEAN_MODULUS)
    log.info("%d plans, %d samples predicted (%.0f s)", args.plans, samples, time.perf_counter() - t1)

    # 2. held-out runs from their own profiles: inside the 90 % interval
    t1 = time.perf_counter()
    recs = predict_recorded_runs(model, held, engine, bound=bound, widths=widths, levels=levels)
    cv = IntervalWidths.from_cv(model)
    O = len(sched.names)
    inside, inside_cv, inside_rms, measured = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    oc_in, oc_n = np.zeros((n, O)), np.zeros((n, O))
    out_in, out_n = np.zeros(n), np.zeros(n)  # samples outside the model's envelope
    per_run: list[list[float]] = [[] for _ in range(n)]
    for rec in recs:
        p = rec.prediction
        p_cv, p_rms = with_interval(p, cv), with_interval(p, rms_rule)
        for j in range(n):
            y = rec.measured[:, j]
            ok = np.isfinite(y) & np.isfinite(p.predicted[:, j]) & (p.oc >= 0)
            hit = (y >= p.lo[:, j]) & (y <= p.hi[:, j])
            inside[j] += np.sum(hit[ok])
            np.add.at(oc_in[j], p.oc[ok], hit[ok])
            beyond = ok & p.outside()[:, j]
            out_in[j] += np.sum(hit[beyond])
            out_n[j] += beyond.sum()
            np.add.at(oc_n[j], p.oc[ok], 1)
            inside_cv[j] += np.sum(((y >= p_cv.lo[:, j]) & (y <= p_cv.hi[:, j]))[ok])
            inside_rms[j] += np.sum(((y >= p_rms.lo[:, j]) & (y <= p_rms.hi[:, j]))[ok])
            measured[j] += ok.sum()
            per_run[j].append(float(np.mean(hit[ok])) if ok.any() else np.nan)
    log.info("%d held-out runs predicted (%.0f s)", len(held), time.perf_counter() - t1)

    print(f"\nengine seed {seed}: {len(train)} training runs, {len(held)} held out, plateaus x "
          f"{args.plateau_scale:g}; training nB {lo:,.0f}-{hi:,.0f} rpm; model {args.targets}")
    print(f"bound: [0, {BOUND_FACTOR:g} x the training runs' largest in the OC within "
          f"{BOUND_WINDOW_RPM:g} rpm]")
    print(f"interval: {widths.describe()}")
    bound_ok, cover_ok = _bounded(within, total), _covered(inside, measured)
    for j, tg in enumerate(model.targets):
        share = within[j] / max(total[j], 1)
        ok = bool(bound_ok[j])
        print(f"{_verdict(ok)}  {tg} plans: {int(within[j])} of {int(total[j])} predicted samples "
              f"({share:.2%}) within the bound over {args.plans} plans (target: all); the node's own "
              f"before the bounds {raw_within[j] / max(total[j], 1):.2%}, bounds acted on {int(acted[j])}; "
              f"{int(mean_mod[j])} from 1x-vector models took the mean modulus")
    for j, tg in enumerate(model.targets):
        cover = inside[j] / max(measured[j], 1)
        ok = bool(cover_ok[j])
        runs = ", ".join(f"{c:.0%}" for c in per_run[j])
        print(f"{_verdict(ok)}  {tg} held-out: {cover:.1%} of {int(measured[j])} measured samples inside the "
              f"90 % interval (target {COVERAGE[0]:.0%}-{COVERAGE[1]:.0%}); per run {runs}; the CV sigma's "
              f"interval alone {inside_cv[j] / max(measured[j], 1):.1%}; the RMS rule before (symmetric, "
              f"t sqrt(1+1/n) x the RMS residual) {inside_rms[j] / max(measured[j], 1):.1%}")
        with np.errstate(invalid="ignore", divide="ignore"):
            per_oc = oc_in[j] / oc_n[j]
        print(f"      {tg} per OC inside: " + ", ".join(
            f"{name} {c:.0%}" for name, c in zip(sched.names, per_oc) if np.isfinite(c)))
        rest = measured[j] - out_n[j]
        print(f"      {tg} outside the model's envelope (> 1): {int(out_n[j])} of {int(measured[j])} "
              "samples, "
              f"{out_in[j] / max(out_n[j], 1):.1%} of them inside the interval; within it "
              f"{(inside[j] - out_in[j]) / max(rest, 1):.1%}")
        print(f"      {tg} per OC run levels of the training runs' chained residual: mean (shift) / SD "
              "between / SD within, mm/s: " + ", ".join(
                  f"{name} {widths.offsets()[j, o]:+.3g}/{widths.between[j, o]:.3g}/{widths.within[j, o]:.3g}"
                  for o, name in enumerate(sched.names) if np.isfinite(widths.between[j, o])))
    for j, tg in enumerate(model.targets):
        both = np.isfinite(eps_mean[j]) & np.isfinite(eps_node[j])
        changed = both & (np.abs(eps_mean[j] - eps_node[j]) > 1e-12)
        print(f"      {tg} training runs' chained eps_td per OC, the mean modulus for 1x-vector models / the "
              f"node's own (modulus of the mean vector): mean {np.mean(eps_mean[j][both]):.3f} / "
              f"{np.mean(eps_node[j][both]):.3f}; " + (", ".join(
                  f"{sched.names[o]} {eps_mean[j, o]:.3f}/{eps_node[j, o]:.3f}"
                  for o in np.flatnonzero(changed)) or "no OC changed (no 1x-vector model)"))
    log.info("engine seed %d: %.0f s", seed, time.perf_counter() - t0)
    return EngineResult(seed, tuple(model.targets), within, total, inside, measured, per_run)
