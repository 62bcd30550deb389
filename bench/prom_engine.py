"""Parametric ROMs on the engine (dissertation section 6.4).

    python -m bench prom-engine [--variant amp|res|cin] [--engines 23,24,25] [--data DIR]
                                [--default DIR] [--quick] [--ocs B1,B6] [--why]

Does a per-OC parametric model, interpolated to a new run's engine-history parameters,
predict held-out runs better than what the node uses today? Per engine (``T{e}.mcap``:
8 training runs, ``H{e}.mcap``: the next 10 held-out runs, ``T{e}.schedule.toml``) and OC:

* ``pROM 1`` / ``pROM 2``: a library of WDMD models, one per training run (fitted on that
  run's OC segment, the lifting warmed on its past; inputs the standardised switch speed and
  the constant 1), the parameter = that run's engine-history value(s) at the OC switch
  (``hist_thermal``, ``hist_shutdown``, ``hist_energy``: ``with_history`` over training and
  held-out runs in time order, ``RuntimeConfig()``), a :class:`ParametricROM` over the 8
  runs, and for each held-out run the model at its own parameter value, free-run over the
  segment from a state fitted on the last ``SEED`` samples of measured past.
  Chosen by leave-one-run-out CV over the training runs only, per OC: the parameter(s),
  levels, kept modes (n_pairs, n_real), scheme (modal, direct) and the weights:
  ``interp`` (piecewise linear for one parameter, thin-plate RBF for two: the package's
  interpolating weights) or ``regress`` (least-squares line / plane through the samples:
  the weights w = [1, x] pinv([1, P]), which sum to 1 and smooth the run-to-run noise of
  identified models instead of interpolating it).
* ``pROM mean``: the same library and CV with equal weights (the parameter ignored): what
  the modal truncation and observer seeding alone do.
* ``WDMD``: one WDMD on all 8 runs' segments (same inputs, the node's ``StateSpaceModel``,
  levels by the same CV).
* ``default``: today's ``train(..., fleet=fleet_curve(...))`` and ``evaluate`` (its model
  kind); read from ``--default DIR`` (``default-{e}.json``) when there, else trained here.
* ``curve``: the characteristic curve (``baseline_eps``).

``--variant``: ``amp`` the amplitude on the speed; ``res`` the amplitude minus the anchored
vector curve (anchor by CV; for a training run fitted without it), the curve added back;
``cin`` the amplitude on the speed and the curve's prediction. ``StudyROM`` holds what the
engine needed beyond the package's ParametricROM (static gain, pole and parameter ranges).
Numbers are held-out eps_td pooled per OC (``pooled_eps``); the CV eps beside. Results and
conclusion: docs/prom_engine_study.md.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from node.contract import FS
from node.contract.schedule import Schedule
from node.contract.vector import NAN_VECTOR
from node.models.config import RuntimeConfig
from node.models.curve import CurveModel, Variant
from node.models.ocmodel import (
    InputScaling,
    Method,
    StateSpaceModel,
    Trajectory,
    lifted_pair,
)
from node.sysid import WDMD, ParametricROM, StateSpace
from node.sysid.metrics import pooled_eps
from node.sysid.observer import estimate_state
from node.sysid.parametric import ParametricModel
from node.training.runs import Run
from node.training.train import CURVE_CANDIDATES

log = logging.getLogger(__name__)

PARAMS = ("hist_thermal", "hist_shutdown", "hist_energy")
ONE: list[tuple[str, ...]] = [(p,) for p in PARAMS]
TWO: list[tuple[str, ...]] = list(itertools.combinations(PARAMS, 2))
LEVELS = [1, 2, 3]
MODES = [(0, 1), (1, 1), (1, 2)]  # (n_pairs, n_real)
SCHEMES = ["modal", "direct"]
N_TRAIN = 8
SEED = 10  # samples of past the pROM state is fitted on (of 10, 40, 200 on the training runs)
TOL = 10.0  # matching cost accepted: the per-run models of a quasi-static OC hold no common physical modes


@dataclass
class Seg:
    """One OC segment with its past: the model's target y (K,) and inputs U (K, m), start,
    the parameters at the switch; ``base`` (K,) is added to the model's prediction (the
    anchored vector curve for the residual variant, else zeros), ``ref`` (K,) the measured target."""

    run: int
    y: np.ndarray
    U: np.ndarray
    start: int
    p: dict[str, float]
    base: np.ndarray
    ref: np.ndarray
    z: np.ndarray | None = None  # the 1x vectors (K,) complex

    def pair(self, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(measured, predicted) over the segment for ``pooled_eps``."""
        return self.ref[self.start:], pred + self.base[self.start:]


class StudyROM(ParametricROM):
    """ParametricROM with two more weight rules for the study: ``regress`` (the least-squares
    hyperplane through the samples, evaluated at p) and ``mean`` (equal weights); and, with
    ``static``, each sample's D set so that its kept modes keep the full model's static gain
    (see ``at``: modal truncation with static correction)."""

    rule = "interp"
    static = True

    def fit(self, samples: object, params: object) -> StudyROM:
        super().fit(samples, params)
        self.dc_ = np.stack([_dc(est.model_) for est in self.estimators_])  # (n, p, m)
        return self

    def _interpolate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The package's interpolation, each pole's real and imaginary parts then clipped to the
        library's range for that mode: weights with negative entries (the least-squares line,
        Lagrange) otherwise move a slow real pole onto z = 1 (an integrator; eps_td 1e6-1e8)."""
        s, R = super()._interpolate(w)
        re = np.clip(s.real, self._s.real.min(axis=0), self._s.real.max(axis=0))
        im = np.clip(s.imag, self._s.imag.min(axis=0), self._s.imag.max(axis=0))
        return re + 1j * im, R

    def at(self, p: object) -> ParametricModel:
        """The interpolated modes; with ``static``, D such that the static gain is the weighted
        sum of the samples' full static gains (the modes near z = 1 of a quasi-static OC carry
        it as R / (1 - z): interpolating R and z separately would scramble it)."""
        if not self.static:
            return super().at(p)
        w = self.weights_at(p)
        s, R = self._interpolate(w)
        bare = self._statespace(s, R, np.zeros_like(self.D_[0]))
        D = np.einsum("i,ipm->pm", w, self.dc_) - _dc(bare)
        return ParametricModel(self._statespace(s, R, D))

    def weights_at(self, p: object) -> np.ndarray:
        if self.rule == "interp":
            return super().weights_at(p)
        P = self.params_ / self._scale
        n = len(P)
        if self.rule == "mean":
            return np.full(n, 1.0 / n)
        x = np.asarray(p, dtype=float).reshape(-1) / self._scale
        X = np.column_stack([np.ones(n), P])
        return np.asarray(np.r_[1.0, x] @ np.linalg.pinv(X))


def _dc(ss: StateSpace) -> np.ndarray:
    """Static gain (p, m) of a discrete model: C (I - A)^-1 B + D."""
    return np.asarray(ss.C @ np.linalg.solve(np.eye(ss.n_states) - ss.A, ss.B) + ss.D)


_LIB: dict[tuple, StateSpace] = {}  # (engine, oc, levels, run) -> the run's fitted WDMD


class Prefit:
    """A base estimator that hands back a library model fitted beforehand (key in Y[0, 0])."""

    def __init__(self, key: tuple) -> None:
        self.key = key

    def fit(self, Y: np.ndarray, U: np.ndarray) -> Prefit:
        self.model_ = _LIB[(*self.key, int(np.asarray(Y)[0, 0]))]
        return self


def _lifted(s: Seg, scaling: InputScaling, need: int) -> tuple[np.ndarray, np.ndarray]:
    """The segment with ``need`` samples of past (the first held where the run has fewer)."""
    return lifted_pair(Trajectory(s.y, s.U, s.start), scaling, need)


def fit_library(key: tuple, segs: list[Seg], scaling: InputScaling, levels: int) -> None:
    """Per run: a WDMD on its segment(s) of this OC (``_LIB``)."""
    for run in sorted({s.run for s in segs}):
        if (*key, levels, run) in _LIB:
            continue
        est = WDMD(levels=levels, rcond=1e-8, dt=1.0 / FS, seed_window=0)
        need = est.memory()
        est.warmup = need
        pairs = [_lifted(s, scaling, need) for s in segs if s.run == run]
        est.fit([p[0] for p in pairs], [p[1] for p in pairs])
        _LIB[(*key, levels, run)] = est.model_


def seed(ss: StateSpace, y: np.ndarray, U: np.ndarray, window: int) -> np.ndarray:
    """The state after the past y (K1,), U (K1, m): least squares over its last ``window``
    samples around the equilibrium of the window's first input (directions the window
    cannot tell keep the equilibrium)."""
    n = ss.n_states
    if len(y) == 0:
        return np.zeros(n)
    W = min(window, len(y))
    x_eq = np.linalg.solve(np.eye(n) - ss.A, ss.B @ U[-W])
    return estimate_state(ss, y[-W:, None], U[-W:], x_eq, rcond=1e-4)


def predict_prom(rom: StudyROM, s: Seg, names: tuple[str, ...], scaling: InputScaling,
                 window: int = SEED) -> np.ndarray:
    """Free run over the segment of the model at the segment's own parameter value(s) (each
    clipped to the library's range: a least-squares plane extrapolated in two parameters
    gave eps_td of 1e6-1e8 on held-out runs outside the training runs' hull)."""
    seg = s.y[s.start:]
    try:
        with np.errstate(all="ignore"):
            # never beyond the library's range: clipped per parameter
            m = rom.at(np.clip([s.p[n] for n in names], rom.params_.min(axis=0), rom.params_.max(axis=0)))
            U = scaling.apply(s.U)
            x0 = seed(m.model_, s.y[:s.start], U[:s.start], window)
            pred = m.simulate(U[s.start:], x0=x0)[:, 0]
    except (np.linalg.LinAlgError, ValueError):
        return np.full(seg.shape, np.inf)
    return np.where(np.isfinite(pred), pred, np.inf)


def build_rom(key: tuple, runs: list[int], params: np.ndarray, levels: int, modes: tuple[int, int],
              scheme: str, rule: str) -> StudyROM | None:
    # residues as identified: the samples handed to fit are keys of models fitted beforehand, no data
    rom = StudyROM(Prefit((*key, levels)), n_pairs=modes[0], n_real=modes[1], scheme=scheme, tol=TOL,
                   weights="auto" if params.shape[1] > 1 else "linear", validate="none", residues="model")
    rom.rule = rule
    if rule == "interp" and any(np.ptp(params[np.arange(len(params)) != i], axis=0).min() == 0
                                for i in range(len(params))):
        return None  # repeated parameter values: no interpolation through them
    try:
        with np.errstate(all="ignore"):
            return rom.fit([(np.array([[r]]), np.zeros((1, 1))) for r in runs], params)
    except (np.linalg.LinAlgError, ValueError):
        return None


def rom_params(segs_by_run: dict[int, list[Seg]], runs: list[int], names: tuple[str, ...]) -> np.ndarray:
    return np.array([[segs_by_run[r][0].p[n] for n in names] for r in runs])


@dataclass
class Choice:
    cv: float
    names: tuple[str, ...]
    levels: int
    modes: tuple[int, int]
    scheme: str
    rule: str

    def label(self) -> str:
        return (f"{'+'.join(n.removeprefix('hist_') for n in self.names) or '-'} L{self.levels} "
                f"{self.modes[0]}c{self.modes[1]}r {self.scheme[0]} {self.rule}")


def cv_prom(key: tuple, train: list[Seg], scaling: InputScaling, sets: list[tuple[str, ...]],
            rules: list[str], quick: bool) -> Choice:
    """Leave-one-run-out CV over the training runs: the best setting for these parameter sets."""
    by_run: dict[int, list[Seg]] = {}
    for s in train:
        by_run.setdefault(s.run, []).append(s)
    runs = sorted(by_run)
    best = Choice(float("inf"), (), 0, (0, 0), "", "")
    levels = LEVELS[:2] if quick else LEVELS
    for lv in levels:
        fit_library(key, train, scaling, lv)
        for names, modes, scheme, rule in itertools.product(sets, MODES, SCHEMES, rules):
            if not all(np.isfinite(s.p[n]) for s in train for n in names):
                continue
            pairs: list[tuple[np.ndarray, np.ndarray]] = []
            for f in runs:
                rest = [r for r in runs if r != f]
                rom = build_rom(key, rest, rom_params(by_run, rest, names), lv, modes, scheme, rule)
                if rom is None:
                    pairs = []
                    break
                pairs += [s.pair(predict_prom(rom, s, names, scaling)) for s in by_run[f]]
            eps = pooled_eps(pairs) if pairs else float("inf")
            if eps < best.cv:
                best = Choice(eps, names, lv, modes, scheme, rule)
    return best


def held_out_prom(key: tuple, train: list[Seg], test: list[Seg], scaling: InputScaling, c: Choice) -> float:
    if not np.isfinite(c.cv):
        return float("nan")
    by_run: dict[int, list[Seg]] = {}
    for s in train:
        by_run.setdefault(s.run, []).append(s)
    runs = sorted(by_run)
    rom = build_rom(key, runs, rom_params(by_run, runs, c.names), c.levels, c.modes, c.scheme, c.rule)
    if rom is None:
        return float("nan")
    return pooled_eps([s.pair(predict_prom(rom, s, c.names, scaling)) for s in test])


def wdmd_plain(train: list[Seg], test: list[Seg]) -> tuple[float, float, int]:
    """One WDMD over every training run (the node's StateSpaceModel, input the switch speed),
    levels by leave-one-run-out CV: (held-out eps, CV eps, levels)."""
    def traj(s: Seg) -> Trajectory:
        return Trajectory(s.y, s.U, s.start)

    def score(model: StateSpaceModel, segs: list[Seg]) -> list[tuple[np.ndarray, np.ndarray]]:
        out = []
        for s in segs:
            with np.errstate(all="ignore"):
                p = model.predict(traj(s))
            out.append(s.pair(np.where(np.isfinite(p), p, np.inf)))
        return out

    runs = sorted({s.run for s in train})
    best = (float("inf"), LEVELS[0])
    for lv in LEVELS:
        pairs: list[tuple[np.ndarray, np.ndarray]] = []
        for f in runs:
            try:
                m = StateSpaceModel.fit(Method.WDMD, {"levels": lv, "rcond": 1e-8},
                                        [traj(s) for s in train if s.run != f])
            except (np.linalg.LinAlgError, ValueError):
                pairs = []
                break
            pairs += score(m, [s for s in train if s.run == f])
        eps = pooled_eps(pairs) if pairs else float("inf")
        if eps < best[0]:
            best = (eps, lv)
    m = StateSpaceModel.fit(Method.WDMD, {"levels": best[1], "rcond": 1e-8}, [traj(s) for s in train])
    return pooled_eps(score(m, test)), best[0], best[1]


def _recordings(data: Path, e: str) -> tuple[Path, Path]:
    """``T{e}.mcap`` and ``H{e}.mcap`` in ``data`` when there; else the development engine ``e``
    of ``bench generalise`` (its schedule and noise), simulated into ``data`` once."""
    if (data / f"T{e}.mcap").exists():
        return data / f"T{e}.mcap", data / f"H{e}.mcap"
    from bench.generalise import SETS, simulate
    engine = next((x for x in SETS["dev"] if str(x.seed) == e), None)
    if engine is None:
        raise SystemExit(f"no T{e}.mcap in {data}, and {e} is no development engine of bench generalise")
    data.mkdir(parents=True, exist_ok=True)
    return simulate(engine, data)


def engine_segments(data: Path, e: str) -> tuple[Schedule, list[list[Seg]], list[Run], list[Run]]:
    """The schedule, per OC its segments (runs 0-7 training, 8-17 held-out), and the runs."""
    from node.contract.schedule import load_schedule
    from node.runtime.history import HISTORY_CHANNELS
    from node.training.dataset import with_history
    from node.training.fit import load_runs
    from node.training.train import oc_datasets

    train, test = _recordings(data, e)
    sched = load_schedule(train.with_suffix(".schedule.toml"))
    tr = load_runs([str(train)], quiet=True)
    te = load_runs([str(test)], quiet=True)
    assert len(tr) == N_TRAIN, len(tr)
    runs = with_history(tr + te, sched, RuntimeConfig())
    cols = [sched.switch, *HISTORY_CHANNELS]
    per_oc = []
    for d in oc_datasets(runs, sched, "yB", cols, history_s=RuntimeConfig().history_s):
        segs: list[Seg] = []
        for run, y, X, start in zip(d.runs, d.y, d.X, d.start):
            at = X[max(start - 1, 0)]
            segs.append(Seg(run, y, X[:, :1], start, {c: float(at[cols.index(c)]) for c in HISTORY_CHANNELS},
                            np.zeros(len(y)), y, d.z[len(segs)] if d.z else None))
        per_oc.append(segs)
    return sched, per_oc, tr, te


VECTOR_CURVES = [c for c in CURVE_CANDIDATES if c["variant"] == Variant.VECTOR and c["window"] == 0]


def curve_track(model: CurveModel, s: Seg) -> np.ndarray:
    """The anchored vector curve's predicted amplitude (K,) over the whole trajectory: anchored
    on the past as at the switch, then looked up at every sample's speed (past ones too)."""
    rt = model.runtime()
    z = s.z if s.z is not None else np.full(len(s.y), NAN_VECTOR)
    rt.start(z[:s.start], s.U[:s.start, :1])
    return np.array([rt.step([x]) for x in s.U[:, 0].tolist()], dtype=float)


def with_curve(segs: list[Seg], how: str) -> tuple[list[Seg], str, float]:
    """The segments for the ``res`` (target y minus the curve, the curve added back) or ``cin``
    (the curve an extra input) variant: the vector curve (window 0; anchor chosen by
    leave-one-run-out CV on the training runs), fitted without the run itself for training
    runs, on all training runs for held-out ones. Also its label and held-out eps alone."""
    train = [s for s in segs if s.run < N_TRAIN]
    runs = sorted({s.run for s in train})

    def traj(s: Seg) -> Trajectory:
        return Trajectory(s.ref, s.U[:, :1], s.start, s.z)

    best: tuple[float, dict] = (float("inf"), VECTOR_CURVES[0])
    for params in VECTOR_CURVES:
        pairs = []
        for f in runs:
            m = CurveModel.fit(Method.CURVE, params, [traj(s) for s in train if s.run != f])
            pairs += [(s.ref[s.start:], m.predict(traj(s))) for s in train if s.run == f]
        eps = pooled_eps(pairs)
        if eps < best[0]:
            best = (eps, params)
    models = {f: CurveModel.fit(Method.CURVE, best[1], [traj(s) for s in train if s.run != f]) for f in runs}
    full = CurveModel.fit(Method.CURVE, best[1], [traj(s) for s in train])
    out = []
    for s in segs:
        c = curve_track(models.get(s.run, full), s)
        c = np.where(np.isfinite(c), c, 0.0)
        if how == "res":
            out.append(Seg(s.run, s.ref - c, s.U[:, :1], s.start, s.p, c, s.ref, s.z))
        else:
            out.append(Seg(s.run, s.ref, np.column_stack([s.U[:, :1], c]), s.start, s.p, np.zeros(len(c)),
                           s.ref, s.z))
    test = [s for s in out if s.run >= N_TRAIN]
    alone = pooled_eps([(s.ref[s.start:], curve_track(full, s)[s.start:]) for s in test])
    return out, f"anchor {best[1]['anchor']}", alone


def default_scores(e: str, sched: Schedule, tr: list[Run], te: list[Run], cache: Path | None) -> dict:
    path = cache / f"default-{e}.json" if cache else None
    if path is not None and path.exists():
        return dict(json.loads(path.read_text()))
    from node.training.evaluation import baseline_eps, evaluate
    from node.training.train import fleet_curve, train

    fleet = fleet_curve(tr, sched.switch, "yB")
    res = train(tr, sched, target="yB", fleet=fleet, workers=1)
    ev, _ = evaluate(res, te, sched, "yB", fleet)
    base = baseline_eps(tr, te, sched, "yB")
    out = {}
    for r, x, b in zip(res, ev, base):
        kind = "-" if r.model is None else r.model.method.value
        if kind == "curve":
            kind += ":" + str(r.params.get("variant", ""))
        out[x.name] = {"eps": x.eps, "kind": kind, "cv": r.cv_eps, "curve": b}
    if path is not None:
        path.write_text(json.dumps(out, indent=1))
    return out


def why(data: Path, engines: list[str]) -> None:
    """Per OC: Pearson r over all 18 runs of each parameter with the run's mean level over the OC
    and with the run's mean relative residual of the anchored vector curve (``--why``)."""
    for e in engines:
        sched, per_oc, _, _ = engine_segments(data, e)
        head = ", ".join(PARAMS)
        print(f"\nengine {e}: | OC | r with the level: {head} | r with the curve residual |")
        rl_all, rr_all = [], []
        for name, segs in zip(sched.names, per_oc):
            rsegs, _, _ = with_curve(segs, "res")
            lvl = np.array([np.mean(s.ref[s.start:]) for s in rsegs])
            res = np.array([np.mean(s.y[s.start:]) / np.mean(s.ref[s.start:]) for s in rsegs])
            P = {n: np.array([s.p[n] for s in rsegs]) for n in PARAMS}
            rl = [float(np.corrcoef(P[n], lvl)[0, 1]) for n in PARAMS]
            rr = [float(np.corrcoef(P[n], res)[0, 1]) for n in PARAMS]
            rl_all.append(np.abs(rl))
            rr_all.append(np.abs(rr))
            print(f"| {name} | " + " ".join(f"{v:+.2f}" for v in rl) + " | "
                  + " ".join(f"{v:+.2f}" for v in rr) + " |")
        print("| mean abs r | " + " ".join(f"{v:.2f}" for v in np.mean(rl_all, axis=0)) + " | "
              + " ".join(f"{v:.2f}" for v in np.mean(rr_all, axis=0)) + " |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench prom-engine")
    ap.add_argument("--engines", default="23,24,25")
    ap.add_argument("--data", default="out/bench/engines",
                    help="T{e}.mcap / H{e}.mcap per engine; missing ones are simulated there")
    ap.add_argument("--default", help="folder of default-{e}.json (today's model's scores; written there)")
    ap.add_argument("--quick", action="store_true", help="levels 1-2 only")
    ap.add_argument("--ocs", help="only these OCs (comma-separated names)")
    ap.add_argument("--variant", choices=["amp", "res", "cin"], default="amp",
                    help="amp: the amplitude on the speed; res: the residual of the anchored vector "
                         "curve; cin: the amplitude on the speed and the vector curve's prediction")
    ap.add_argument("--why", action="store_true", help="only the correlations of the history "
                    "parameters with each run's level and curve residual, per OC")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if args.why:
        why(Path(args.data), args.engines.split(","))
        return 0
    cache = Path(args.default) if args.default else None
    rows = []
    cands: list[tuple[float, float, float, float]] = []
    for e in args.engines.split(","):
        t0 = time.perf_counter()
        sched, per_oc, tr, te = engine_segments(Path(args.data), e)
        dflt = default_scores(e, sched, tr, te, cache)
        print(f"\nengine {e} ({len(sched.names)} OCs), variant {args.variant}")
        print("| OC | pROM 1 | its choice (CV) | pROM 2 | its choice (CV) | pROM mean (CV) | WDMD (CV, L) "
              "| vector curve (anchor) | default | default's kind | curve |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for name, segs in zip(sched.names, per_oc):
            if args.ocs and name not in args.ocs.split(","):
                continue
            train = [s for s in segs if s.run < N_TRAIN]
            test = [s for s in segs if s.run >= N_TRAIN]
            if len({s.run for s in train}) < 3 or not test:
                continue
            vec, vlabel = float("nan"), "-"
            if args.variant != "amp":
                segs, vlabel, vec = with_curve(segs, args.variant)
                train = [s for s in segs if s.run < N_TRAIN]
                test = [s for s in segs if s.run >= N_TRAIN]
            scaling = InputScaling.fit(np.vstack([s.U[s.start:] for s in train]))
            key = (e, name, args.variant)
            c1 = cv_prom(key, train, scaling, ONE, ["interp", "regress"], args.quick)
            c2 = cv_prom(key, train, scaling, TWO, ["interp", "regress"], args.quick)
            c0 = cv_prom(key, train, scaling, [()], ["mean"], args.quick)
            p1, p2, p0 = (held_out_prom(key, train, test, scaling, c) for c in (c1, c2, c0))
            w, wcv, wl = wdmd_plain(train, test)
            d = dflt[name]
            rows.append((e, name, p1, p2, p0, w, vec, d["eps"], d["curve"]))
            # a pROM as one more CV candidate per OC: the better of pROM 1 and 2 by CV replaces
            # today's model when its CV eps is below (1 - margin) x today's CV eps
            cv_p, held_p = min((c1.cv, p1), (c2.cv, p2))
            cands.append((cv_p, held_p, float(d["cv"]), float(d["eps"])))
            print(f"| {name} | {p1:.3f} | {c1.label()} ({c1.cv:.3f}) | {p2:.3f} | {c2.label()} ({c2.cv:.3f}) "
                  f"| {p0:.3f} ({c0.cv:.3f}) | {w:.3f} ({wcv:.3f}, {wl}) | {vec:.3f} ({vlabel}) "
                  f"| {d['eps']:.3f} | {d['kind']} "
                  f"| {d['curve']:.3f} |", flush=True)
        mine = np.array([r[2:] for r in rows if r[0] == e], dtype=float)
        m = np.nanmean(mine, axis=0)
        print(f"| mean | {m[0]:.3f} | | {m[1]:.3f} | | {m[2]:.3f} | {m[3]:.3f} | {m[4]:.3f} | {m[5]:.3f} | "
              f"| {m[6]:.3f} |")
        print(f"({time.perf_counter() - t0:.0f} s)", flush=True)
    a = np.array([r[2:] for r in rows], dtype=float)
    print(f"\nall: {len(rows)} OCs, mean held-out eps_td")
    for label, j in (("pROM 1", 0), ("pROM 2", 1), ("pROM mean", 2), ("WDMD", 3), ("vector curve", 4),
                     ("default", 5), ("curve", 6)):
        wins = int(np.sum(a[:, j] < a[:, 5])) if j != 5 else 0
        print(f"| {label} | {np.nanmean(a[:, j]):.3f} | below default in {wins} of {len(a)} OCs |")
    c = np.array(cands)
    for margin in (0.0, 0.5):
        take = c[:, 0] < (1.0 - margin) * c[:, 2]
        mixed = np.where(take, c[:, 1], c[:, 3])
        print(f"| default + pROM candidate (margin {margin:g}) | {np.nanmean(mixed):.3f} | pROM taken in "
              f"{int(take.sum())} of {len(c)} OCs |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
