"""Study: can any vector rule see a nominal stiffness loss within a minute?

    python -m bench stiffness-drift [--workdir W[,W2]] [--seeds 14,15,16]

On ``bench faults``'s recordings (``engine{seed}/`` in one of the work dirs: training runs,
normal held-out runs whose first is each fault run's *twin*, ``stiffness-{1,2,3}.mcap`` with
their truth), per stiffness onset, three measures over the 60 s after it:

* effect: what the fault did to the order's 1x vector, the largest 1 s mean of |fault run -
  twin| (mm/s; the runs are equal sample for sample before the onset), anywhere and within
  the onset's own plateau, and where it is largest (OC, steady or transition);
* drift: per steady plateau (after 3 s of settling) the 1x vector minus its mean over the
  plateau's first 4 s (the anchored vector check's reference), as a 1 s mean over the noise
  of a 1 s mean (the training runs' first differences per OC): ``raw``. ``comp``: the same
  after removing a per-OC complex gain times the change of the slow temperatures (tF, tI, tH)
  since that reference, the gains by least squares over the training runs' plateaus. The
  largest within 60 s over the largest of any normal held-out plateau of the same OC;
* residual: the 1x vector against an influence curve (``CurveModel``, variant influence:
  each speed's vector an affine function of the vector over the 1 s before the OC switch)
  fitted on the training runs, over the whole OC segment (transition and plateau), divided
  by its leave-one-run-out sigma per 50 rpm speed bin, smoothed as the residual rule smooths
  (``EWMA_ALPHA``); its largest |score| within 60 s over the largest of any normal held-out
  run in the same OC.

Last, the node's anchored vector check alone (``StepCheck``, the bundle's settings) with the
bundle's threshold (one for every OC, pooled) against per-OC thresholds, K times the OC's
largest training plateau peak: stiffness onsets flagged within 60 s, normal plateaus flagged.

A ratio beyond 1 means a rule of that kind with a threshold just above every normal held-out
run (no false alarm there, the most sensitive such rule could be) would flag the onset in
time: the count of such onsets bounds what these rules can reach. A study, not the product.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from harness.fault_effect import on_common_samples
from node.contract import FS, Phase
from node.contract.schedule import Schedule, load_schedule
from node.contract.vector import order_vectors
from node.models.bundle import load_bundle
from node.models.config import RuntimeConfig
from node.models.curve import CurveModel
from node.models.ocmodel import Method, Trajectory
from node.models.result import EWMA_ALPHA
from node.runtime.alarms import StepCheck
from node.runtime.ocdetect import OCDetector
from node.training.calibrate import DRIFT_OC_FACTOR, drift_thresholds, plateau_peaks
from node.training.dataset import fill_gaps, target_vectors
from node.training.ocdata import OCData
from node.training.runs import Run, read_runs
from node.training.train import oc_datasets

TEMPS = ["tF", "tI", "tH"]
CH = ["nB", "yB", "yB_ph", *TEMPS]
SETTLE, LONG, SHORT = int(3 * FS), int(4 * FS), int(1 * FS)
WINDOW_S = 60.0  # a stiffness loss should be flagged within this, s
INFLUENCE = {"variant": "influence", "bin": 25.0, "anchor": int(FS)}
SIGMA_BIN = 50.0  # rpm: the residual's sigma per speed bin of this width
PER_OC = (1.5, 2.0, 2.5, 3.0)  # per-OC drift thresholds tried: these times the OC's largest training peak

def plateaus(run: Run, sched: Schedule) -> list[tuple[int, int, int]]:
    """(oc, first, last sample) of each steady plateau."""
    det = OCDetector(sched, RuntimeConfig(), FS)
    sp = run.column("nB")
    out: list[tuple[int, int, int]] = []
    cur: list[int] | None = None
    for k, v in enumerate(sp.tolist()):
        st = det.step(v)
        if st.phase is Phase.STEADY and st.oc is not None:
            if cur is None:
                cur = [st.oc, k, k]
            cur[2] = k
        elif cur is not None:
            out.append((cur[0], cur[1], cur[2]))
            cur = None
    if cur is not None:
        out.append((cur[0], cur[1], cur[2]))
    return out

def plateau_data(run: Run, sched: Schedule) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """Per plateau: oc, first sample after settling, the vector and temperatures from their reference."""
    z = target_vectors(run, "yB")  # amplitude and phase held over gaps, as training holds them
    if z is None:
        raise SystemExit("the recordings hold no yB_ph: simulate them with the phase channels")
    T = fill_gaps(np.column_stack([run.column(c) for c in TEMPS]))
    for oc, a, b in plateaus(run, sched):
        a0 = a + SETTLE
        if b - a0 < LONG + SHORT:
            continue
        zr = z[a0:b + 1] - np.nanmean(z[a0:a0 + LONG])
        Tr = T[a0:b + 1] - np.nanmean(T[a0:a0 + LONG], axis=0)
        yield oc, a0, zr, Tr

def fit_gains(items: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Complex gains (m,) of the temperature changes on the vector change, least squares."""
    X = np.vstack([Tr for Tr, _ in items])
    Z = np.concatenate([zr for _, zr in items])
    ok = np.isfinite(Z) & np.isfinite(X).all(axis=1)
    X, Z = X[ok], Z[ok]
    Xs = X.std(axis=0) + 1e-12
    g: np.ndarray = np.linalg.lstsq(X / Xs, Z, rcond=None)[0] / Xs
    return g

def stat(zr: np.ndarray, Tr: np.ndarray, g: np.ndarray | None, noise: float) -> np.ndarray:
    """|1 s mean of the drift (less the temperatures' share)| over the noise of a 1 s mean."""
    r = zr - Tr @ g if g is not None else zr
    m = np.convolve(np.nan_to_num(r), np.ones(SHORT) / SHORT, mode="same")
    out: np.ndarray = np.abs(m) / noise
    return out

def window_mask(run: Run, first: int, n: int, onset: float) -> np.ndarray:
    """(n,) which of run's samples first .. first + n - 1 lie within WINDOW_S of the onset."""
    t = run.t[first:first + n]
    return (t >= onset) & (t <= onset + WINDOW_S)


def effect(run: Run, twin: Run, sched: Schedule, onset: float) -> tuple[float, float, str]:
    """The fault's largest 1 s mean |vector change| within WINDOW_S (mm/s), the same within the
    onset's own plateau, and where the first is largest ("OC7 steady")."""
    run, twin = on_common_samples(run, twin)
    za, zb = target_vectors(run, "yB"), target_vectors(twin, "yB")
    assert za is not None and zb is not None
    d = np.nan_to_num(za - zb)
    m = np.abs(np.convolve(d, np.ones(SHORT) / SHORT, mode="full")[:len(d)])  # the 1 s before each
    win = window_mask(run, 0, len(d), onset)
    own = np.zeros(len(d), bool)
    for _oc, a, b in plateaus(run, sched):
        if run.t[a] <= onset <= run.t[b]:
            own[a:b + 1] = True
    k = int(np.flatnonzero(win)[np.argmax(m[win])])
    oc, phase = OCDetector(sched, RuntimeConfig(), FS).label(run.column("nB"))
    where = f"{sched.segments[oc[k]]} {Phase.from_code(int(phase[k])).value}" if oc[k] >= 0 else "-"
    return float(m[win].max()), float(m[win & own].max()) if (win & own).any() else 0.0, where


def _trajectory(d: OCData, i: int) -> Trajectory:
    return Trajectory(d.y[i], d.X[i], d.start[i], d.z[i])


def _vector_residual(model: CurveModel, d: OCData, i: int) -> np.ndarray:
    """(K_seg,) measured minus predicted 1x vector over segment i's OC samples."""
    t = _trajectory(d, i)
    rt = model.runtime()
    rt.start(d.z[i][:t.start], t.U[:t.start])
    pred: np.ndarray = rt.speeds_ahead(t.seg_U[:, 0])
    return d.z[i][t.start:] - pred


class BinSigma:
    """The sd of a complex residual's components per speed bin (SIGMA_BIN rpm wide). At a
    speed: the largest of its bin's and its two neighbours'; where none of the three has
    samples (or the speed is NaN), the sd of every sample."""

    def __init__(self, residuals: list[np.ndarray], speeds: list[np.ndarray]) -> None:
        r, x = np.concatenate(residuals), np.concatenate(speeds)
        ok = np.isfinite(r) & np.isfinite(x)
        r, b = r[ok], np.floor(x[ok] / SIGMA_BIN).astype(int)
        self.every = float(np.sqrt(np.mean(np.abs(r) ** 2) / 2))
        self.table = {int(k): float(np.sqrt(np.mean(np.abs(r[b == k]) ** 2) / 2)) for k in np.unique(b)}

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.full(len(x), self.every)
        for k, v in enumerate(x.tolist()):
            if v == v:
                b = int(v // SIGMA_BIN)
                near = [self.table[j] for j in (b - 1, b, b + 1) if j in self.table]
                out[k] = max(near) if near else self.every
        return out


def ewma_score(residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(K,) |EWMA of residual / sigma| (the residual rule's smoothing; NaN holds the score)."""
    e, out = 0j, np.zeros(len(residual))
    for k, (r, s) in enumerate(zip(residual.tolist(), sigma.tolist())):
        if r == r:
            e = (1.0 - EWMA_ALPHA) * e + EWMA_ALPHA * r / s
        out[k] = abs(e)
    return out


def influence_rule(train: list[Run], sched: Schedule) -> dict[str, tuple[CurveModel, BinSigma]]:
    """Per OC: the influence curve of every training run, and its leave-one-run-out sigma per bin."""
    out = {}
    for d in oc_datasets(train, sched, "yB", ["nB"]):
        if len(d.runs) < 3 or not d.z:
            continue
        rows = range(len(d.runs))
        res, speeds = [], []
        for i in rows:
            m = CurveModel.fit(Method.CURVE, INFLUENCE, [_trajectory(d, j) for j in rows if j != i])
            res.append(_vector_residual(m, d, i))
            speeds.append(d.X[i][d.start[i]:, 0])
        out[d.name] = (CurveModel.fit(Method.CURVE, INFLUENCE, [_trajectory(d, j) for j in rows]),
                       BinSigma(res, speeds))
    return out


def influence_scores(runs: list[Run], sched: Schedule, rule: dict[str, tuple[CurveModel, BinSigma]]
                     ) -> Iterator[tuple[str, int, int, np.ndarray]]:
    """(OC, run index, first sample in the run, EWMA |score| per OC sample) of every segment."""
    for d in oc_datasets(runs, sched, "yB", ["nB"]):
        if d.name not in rule:
            continue
        model, sigma = rule[d.name]
        for i in range(len(d.runs)):
            yield d.name, d.runs[i], d.at[i], ewma_score(_vector_residual(model, d, i),
                                                         sigma(d.X[i][d.start[i]:, 0]))


def drift_peaks(run: Run, sched: Schedule, config: RuntimeConfig) -> list[tuple[int, int, np.ndarray]]:
    """The node's anchored vector check over one run: per steady plateau long enough for it,
    (OC, first sample, the level its statistic holds for the check's persist samples, per sample)."""
    det = OCDetector(sched, config, FS)
    oc, phase = det.label(run.column("nB"))
    chk = StepCheck(math.inf, config, FS, anchored=True)
    z = order_vectors(run.column("yB"), run.column("yB_ph"))
    out: list[tuple[int, int, np.ndarray]] = []
    cur: list[float] = []
    first = 0
    for k, (v, p) in enumerate(zip(z.tolist(), (phase == Phase.STEADY.code).tolist())):
        stat_k = chk.step(v, p)
        if p:
            if not cur:
                first = k
            cur.append(stat_k)
        if cur and (not p or k == len(z) - 1):
            x = np.asarray(cur)
            if len(x) >= chk.n_settle + chk.n_short + chk.n_long + chk.persist:
                held = np.lib.stride_tricks.sliding_window_view(x, chk.persist).min(axis=1)
                out.append((int(oc[first]), first, np.concatenate([np.zeros(chk.persist - 1), held])))
            cur = []
    return out


def per_oc_thresholds(W: Path, sched: Schedule, train: list[Run], normal: list[Run],
                      faults: list[tuple[dict, Run]]) -> dict[str, tuple[int, int]]:
    """Per threshold scheme: (stiffness onsets its anchored check flags within WINDOW_S, normal
    held-out plateaus it flags). ``pooled``: the bundle's one threshold for every OC; ``xK``:
    K times the OC's largest training peak (``drift_thresholds`` with K for its factor; the
    pooled one where the OC has too few plateaus)."""
    bundle = load_bundle(W / "model-wdmd")
    pooled = float(bundle.checks["vector_drift_threshold"])
    found: list[tuple[int, float]] = []  # training's (OC, peak) of each plateau, as calibration finds them
    for r in train:
        ocs, phase = OCDetector(sched, bundle.config, FS).label(r.column("nB"))
        z = order_vectors(r.column("yB"), r.column("yB_ph"))
        found += plateau_peaks(z, phase, bundle.config, FS, True, ocs)
    schemes = {"pooled": dict.fromkeys(range(len(sched.names)), pooled)}
    for k in PER_OC:
        per_oc = drift_thresholds([(o, k / DRIFT_OC_FACTOR * p) for o, p in found], sched.names)
        schemes[f"x{k:g}"] = {oc: per_oc.get(name, pooled) for oc, name in enumerate(sched.names)}
    normal_peaks = [(oc, float(h.max())) for r in normal for oc, _, h in drift_peaks(r, sched, bundle.config)]
    fault_peaks = []
    for f, run in faults:
        best: dict[int, float] = {}
        for oc, a, h in drift_peaks(run, sched, bundle.config):
            win = window_mask(run, a, len(h), f["onset"])
            if win.any():
                best[oc] = max(best.get(oc, 0.0), float(h[win].max()))
        fault_peaks.append(best)
    return {name: (sum(any(v > thr[oc] for oc, v in b.items()) for b in fault_peaks),
                   sum(v > thr[oc] for oc, v in normal_peaks)) for name, thr in schemes.items()}


def _engine_dir(works: list[Path], seed: int) -> Path:
    for w in works:
        if (w / f"engine{seed}" / "stiffness-1.truth.json").exists():
            return w / f"engine{seed}"
    raise SystemExit(f"no stiffness recordings of engine {seed} in {', '.join(map(str, works))}: "
                     f"run python -m bench faults --seeds {seed} --faults stiffness --workdir W first")


def study(works: list[Path], engines: list[int]) -> int:
    rows = []
    schemes: dict[str, list[int]] = {}
    print("| engine | onset | effect within 60 s, mm/s | where largest | in its plateau, mm/s "
          "| drift / normal | drift less temperatures / normal | influence residual / normal |")
    print("|---|---|---|---|---|---|---|---|")
    for e in engines:
        W = _engine_dir(works, e)
        sched = load_schedule(W / "train.schedule.toml")
        train = read_runs(W / "train.mcap", CH)
        by_oc: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for r in train:
            for oc, _, zr, Tr in plateau_data(r, sched):
                by_oc.setdefault(oc, []).append((Tr, zr))
        gains = {oc: fit_gains(v) for oc, v in by_oc.items()}
        noise: dict[int, float] = {}
        for oc, v in by_oc.items():
            d = np.concatenate([np.diff(zr) for _, zr in v])
            d = d[np.isfinite(d)]
            noise[oc] = np.sqrt(np.mean(np.abs(d) ** 2) / 2) / np.sqrt(SHORT)  # sd of a 1 s mean
        normal = read_runs(W / "normal.mcap", CH)
        nmax: dict[tuple[int, str], float] = {}
        for r in normal:
            for oc, _, zr, Tr in plateau_data(r, sched):
                for mode, g in (("raw", None), ("comp", gains.get(oc))):
                    s = stat(zr, Tr, g, noise[oc]).max()
                    nmax[(oc, mode)] = max(nmax.get((oc, mode), 0.0), float(s))
        rule = influence_rule(train, sched)
        rmax: dict[str, float] = {}
        for name, _, _, sc in influence_scores(normal, sched, rule):
            rmax[name] = max(rmax.get(name, 0.0), float(sc.max()))
        faults = []
        for i in (1, 2, 3):
            truth = json.loads((W / f"stiffness-{i}.truth.json").read_text())
            f = truth["runs"][-1]["fault"]
            run = read_runs(W / f"stiffness-{i}.mcap", CH)[-1]
            faults.append((f, run))
            onset = f["onset"]
            res: dict[str, float] = {}
            for oc, a0, zr, Tr in plateau_data(run, sched):
                win = window_mask(run, a0, len(zr), onset)
                if not win.any():
                    continue
                for mode, g in (("raw", None), ("comp", gains.get(oc))):
                    s = stat(zr, Tr, g, noise[oc])[win].max()
                    ratio = s / nmax.get((oc, mode), np.inf)
                    res[mode] = max(res.get(mode, 0.0), float(ratio))
            for name, _, at, sc in influence_scores([run], sched, rule):  # the fault run alone
                win = window_mask(run, at, len(sc), onset)
                if win.any():
                    ratio = float(sc[win].max()) / rmax.get(name, np.inf)
                    res["influence"] = max(res.get("influence", 0.0), ratio)
            size, own, where = effect(run, normal[0], sched, onset)
            row = (e, i, f["oc"], res.get("raw", 0.0), res.get("comp", 0.0), res.get("influence", 0.0), size)
            rows.append(row)
            print(f"| {e} | {f['oc']} | {size:.2f} | {where} | {own:.2f} | {row[3]:.2f} | {row[4]:.2f} "
                  f"| {row[5]:.2f} |", flush=True)
        for name, (hits, false) in per_oc_thresholds(W, sched, train, normal, faults).items():
            tot = schemes.setdefault(name, [0, 0])
            tot[0], tot[1] = tot[0] + hits, tot[1] + false
    a = np.array([r[3:] for r in rows])
    either = (a[:, 0] > 1) | (a[:, 2] > 1)
    print(f"onsets a rule with no false alarm on the normal runs could flag within {WINDOW_S:g} s: drift "
          f"{int((a[:, 0] > 1).sum())}, drift less temperatures {int((a[:, 1] > 1).sum())}, influence "
          f"residual {int((a[:, 2] > 1).sum())}, drift or residual {int(either.sum())}, of {len(rows)}")
    for lim in (1.0, 2.0, 5.0):
        print(f"onsets whose effect within {WINDOW_S:g} s stays below {lim:g} mm/s: "
              f"{int((a[:, 3] < lim).sum())} of {len(rows)}")
    print("the anchored vector check alone, with the bundle's pooled threshold or per-OC ones (xK: K times "
          f"the OC's largest training peak; the default x{DRIFT_OC_FACTOR:g}):")
    for name, (hits, false) in schemes.items():
        print(f"  {name:6s}: stiffness onsets flagged within {WINDOW_S:g} s {hits}/{len(rows)}, "
              f"normal held-out plateaus beyond the threshold {false}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench stiffness-drift")
    ap.add_argument("--workdir", required=True,
                    help="bench faults's work dirs (their recordings), comma-separated")
    ap.add_argument("--seeds", default="14,15,16")
    args = ap.parse_args(argv)
    return study([Path(w) for w in args.workdir.split(",")], [int(s) for s in args.seeds.split(",")])


if __name__ == "__main__":
    raise SystemExit(main())
