"""Held-out accuracy on engines the defaults were not chosen on (the judge of the training defaults).

    python -m bench generalise [--set report|dev|all] [--workdir DIR] [--reuse]

Each engine of the set is simulated by the project's simulator (its own seed: its own
rotor, imbalance, bow and thermal history; shutdowns between runs of 10 minutes to 12 hours),
with one of three schedules (A: the built-in 12 OCs; B: ``harness/schedules/passoff_b.toml``,
9 OCs at other speeds, in another order, shorter plateaus; C: ``passoff_c.toml``, a 4-minute
warm-up at ground idle first, in which a bowed rotor straightens) and one of two noise levels
(x1, x2.5): 8 training runs, then 10 held-out runs of the same engine. Per engine and OC it
prints the mean held-out eps_td of

* ``no phase, held`` / ``no phase``: ``ordervib train --no-phase --no-plateaus --no-settle
  [--no-fade]``,
  the model on the amplitudes alone, its anchored curves held through the OC (the default
  before the phase was used) or learning how their anchor fades (``CurveModel.decay``),
* ``default, held`` / ``default``: ``ordervib train --no-plateaus --no-settle [--no-fade]``, which
  use the order's phase (the recordings carry it: ``yB_ph``),
* ``no phase, guarded`` / ``default, guarded``: the same models as ``no phase`` and
  ``default`` with the curve guard on (``node.runtime.guard``: within an OC visit the curve
  where the model erred more so far); the four columns before are scored with it off,
* ``no phase, plateaus`` / ``default, plateaus``: ``ordervib train [--no-phase] --no-settle``
  (the plateau shift on, ``node.models.plateau``: what the run's earlier plateaus add), scored
  with the curve guard on,
* ``no phase, settle`` / ``default, settle``: ``ordervib train [--no-phase]`` (today's
  defaults: the settle anchor on too, ``node.models.settle``: what the visit's own settled level
  adds), scored with the curve guard on,
* ``curve``: the characteristic-curve baseline,
* ``floor``: the noise floor, the eps_td of a prediction that knew the clean signal (the
  simulator's sensor noise on the measured amplitudes: ``noise_floor``): no model can go below it,

all measured in this one run, then per set the mean, the OCs worse than the curve by more than
5 %, and the same for the first OC of each run (the one after a start, where a bow is). The
defaults were chosen on the ``dev`` engines only; ``report`` (the default set) holds the
others. Simulated recordings are kept in --workdir and reused; with ``--reuse`` the models
found there too (trained by an earlier run of this bench: say which code trained them).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness import make
from node.contract.errors import OrdervibError

SCHEDULES = Path(__file__).resolve().parents[1] / "harness" / "schedules"
SCHEDULE_FILES = {"A": None, "B": SCHEDULES / "passoff_b.toml", "C": SCHEDULES / "passoff_c.toml"}


@dataclass(frozen=True)
class Engine:
    seed: int
    schedule: str  # "A" (built-in), "B" or "C" (SCHEDULE_FILES)
    noise: float

    @property
    def name(self) -> str:
        return f"E{self.seed}{self.schedule}x{self.noise:g}"


SETS = {
    "dev": [Engine(11, "A", 1.0), Engine(12, "A", 1.0), Engine(21, "B", 2.5), Engine(22, "A", 2.5),
            Engine(23, "B", 1.0), Engine(24, "B", 2.5), Engine(25, "A", 2.5), Engine(26, "C", 1.0),
            Engine(27, "C", 2.5)],
    "report": [Engine(37, "C", 1.0), Engine(14, "A", 1.0), Engine(31, "B", 1.0), Engine(38, "C", 2.5),
               Engine(15, "A", 1.0), Engine(32, "B", 1.0), Engine(39, "C", 1.0), Engine(16, "A", 1.0),
               Engine(33, "A", 2.5), Engine(34, "A", 2.5), Engine(35, "B", 2.5), Engine(36, "B", 2.5)],
}


def simulate(e: Engine, work: Path) -> tuple[Path, Path]:
    """The engine's 8 training and 10 held-out runs (reused when already there with the order
    phases; recordings from before the phase channels are simulated again)."""
    train, test = work / f"{e.name}-train.mcap", work / f"{e.name}-test.mcap"
    file = SCHEDULE_FILES[e.schedule]
    common = {"seed": e.seed, "noise_scale": e.noise, "schedule": str(file) if file else None}
    for rec, runs in ((train, {"runs": 8}), (test, {"runs": 18, "skip": 8})):
        truth = rec.with_suffix(".truth.json")
        if rec.exists() and truth.exists() and json.loads(truth.read_text()).get("phase") is not None:
            continue
        for old in (rec, truth, rec.with_suffix(".schedule.toml")):  # this bench's own files
            old.unlink(missing_ok=True)
        make.simulate(rec, **runs, **common)
    return train, test


def train_quietly(train: Path, schedule: Path, model: Path, options: dict) -> bool:
    """The model of TRAIN for yB with the model ``options`` into ``model``; False when it
    failed (said in one line)."""
    try:
        make.train([train], schedule, model, target="yB", **options)
    except OrdervibError as exc:
        print(f"training failed: {exc}")
        return False
    return True


def held_out(model: Path, tr: list, te: list, guard: bool, noise: float = 1.0
             ) -> list[tuple[str, float, str, float, tuple[float, float, float]]]:
    """Per OC: (name, held-out eps_td, model kind, noise floor at ``noise``, ``excess_split``
    of its segments) over the held-out
    runs ``te``, the history derived through the training runs ``tr`` first (as a node that ran
    them would have it); guard: the curve guard on with the product's settings, else off
    (whatever the bundle says)."""
    import dataclasses

    from node.models.bundle import load_bundle
    from node.models.config import RuntimeConfig
    from node.runtime.history import HISTORY_CHANNELS
    from node.training.dataset import with_history
    from node.training.evaluation import evaluate

    b = load_bundle(model)
    product = RuntimeConfig()
    config = dataclasses.replace(b.config, guard_wait_s=product.guard_wait_s if guard else 0.0,
                                 guard_margin=product.guard_margin)
    if any(c in HISTORY_CHANNELS for c in b.inputs):
        te = with_history(tr + te, b.schedule, b.config)[len(tr):]
    evals, preds = evaluate(b.ocs, te, b.schedule, b.target, b.curve, config)
    kinds = {r.name: r.kind for r in b.ocs}
    return [(e.name, e.eps, kinds[e.name],
             noise_floor(np.concatenate([p.measured for p in preds if p.oc == j] or [np.zeros(0)]), noise),
             excess_split([(p.measured, p.predicted) for p in preds if p.oc == j], noise))
            for j, e in enumerate(evals)]


RAMP_S = 15.0  # excess_split: the first seconds of an OC visit, where its transition is


def excess_split(visits: list[tuple[np.ndarray, np.ndarray]], noise: float
                 ) -> tuple[float, float, float]:
    """Where a prediction's error above the noise floor lies, over the OC visits ``visits``
    ((measured, predicted) (K,) each, from the OC switch on): the shares (0-1) of the excess
    squared error (the error's energy less the noise's, ``noise_floor``) that fall in the first
    ``RAMP_S`` of each visit (the transition), in each visit's constant offset after that (its
    mean error there, squared, times its samples: a level the model missed), and the rest (the
    plateau's own wander); NaN without excess.

    >>> t = np.arange(1600) / 40.0  # a 40 s visit: a level missed by 0.5 on the plateau
    >>> y = np.full(t.size, 3.0); p = y + np.where(t < RAMP_S, 0.0, 0.5)
    >>> [round(v, 2) + 0.0 for v in excess_split([(y, p)], noise=0.0)]  # (+ 0.0: no -0.0)
    [0.0, 1.0, 0.0]
    """
    from simulator.campaign import NOISE
    absolute, relative, decimals = NOISE["y"]
    ramp = offset = total = 0.0
    n_ramp = int(RAMP_S * 40)
    for y, p in visits:
        e = np.asarray(y, float) - np.asarray(p, float)
        ok = np.isfinite(e)
        var = np.where(ok, (noise * (absolute + relative * np.abs(np.nan_to_num(y)))) ** 2
                       + (10.0 ** -decimals) ** 2 / 12, 0.0)
        e = np.where(ok, e, 0.0)
        excess = e ** 2 - var
        total += float(excess.sum())
        ramp += float(excess[:n_ramp].sum())
        late = ok[n_ramp:]
        if late.any():
            offset += float(late.sum()) * float(np.mean(e[n_ramp:][late])) ** 2
    if not total > 0:
        return (math.nan, math.nan, math.nan)
    return (ramp / total, offset / total, 1.0 - (ramp + offset) / total)


def noise_floor(measured: np.ndarray, noise: float) -> float:
    """The eps_td of the clean signal against ``measured`` (K,) amplitudes (mm/s), NaN skipped:
    the simulator's sensor noise (sigma = noise x (absolute + relative |y|), then rounding to
    ``decimals``) over the signal's energy; NaN without samples.

    >>> round(noise_floor(np.full(100, 3.0), 1.0), 4)  # (0.03 + 0.02 x 3) / 3, rounding's too
    0.03
    """
    from simulator.campaign import NOISE
    absolute, relative, decimals = NOISE["y"]
    y = measured[np.isfinite(measured)]
    if y.size == 0 or not np.any(y):
        return float("nan")
    var = (noise * (absolute + relative * np.abs(y))) ** 2 + (10.0 ** -decimals) ** 2 / 12
    return float(np.sqrt(np.sum(var) / np.sum(y ** 2)))


def engine_args(name: str, default_set: str, argv: list[str] | None
                ) -> tuple[Path, str, list[Engine], bool]:
    """``--set`` and ``--workdir`` of a bench over these engines: the folder of the recordings
    (made), the set's name, its engines, and --reuse (generalise only; else False)."""
    ap = argparse.ArgumentParser(prog=f"python -m bench {name}")
    ap.add_argument("--set", choices=[*SETS, "all"], default=default_set)
    ap.add_argument("--workdir", help="keep the simulated recordings here (default: a new temp folder)")
    if name == "generalise":
        ap.add_argument("--reuse", action="store_true",
                        help="reuse the models found in --workdir (else each is trained afresh)")
    args = ap.parse_args(argv)
    work = Path(args.workdir or tempfile.mkdtemp(prefix=f"ordervib-{name}-"))
    work.mkdir(parents=True, exist_ok=True)
    engines = SETS["dev"] + SETS["report"] if args.set == "all" else SETS[args.set]
    return work, args.set, engines, bool(getattr(args, "reuse", False))


COLUMNS: tuple[tuple[str, dict], ...] = (
    ("no phase, held", {"phase": False, "fade": False, "plateaus": False, "settle": False}),
    ("no phase", {"phase": False, "plateaus": False, "settle": False}),
    ("default, held", {"fade": False, "plateaus": False, "settle": False}),
    ("default", {"plateaus": False, "settle": False}))
GUARDED = (("no phase, guarded", 1), ("default, guarded", 3))  # the curve guard on that column's model
# trained with the plateau shift (``train --plateaus --no-settle``), then with the settle anchor too
# (today's defaults), scored with the curve guard on (as the node runs)
PLATEAUS: tuple[tuple[str, dict], ...] = (
    ("no phase, plateaus", {"phase": False, "settle": False}), ("default, plateaus", {"settle": False}),
    ("no phase, settle", {"phase": False, "settle": True}), ("default, settle", {"settle": True}))
LABELS = [n for n, _ in COLUMNS] + [n for n, _ in GUARDED] + [n for n, _ in PLATEAUS]


def main(argv: list[str] | None = None) -> int:
    work, set_name, engines, reuse = engine_args("generalise", "report", argv)
    from node.contract.schedule import load_schedule
    from node.training.evaluation import baseline_eps
    from node.training.fit import load_runs

    # engine, OC index, OC, eps per column, curve, kind, noise floor, excess split per column
    rows: list[tuple[str, int, str, list[float], float, str, float, list[tuple[float, float, float]]]] = []
    for e in engines:
        t0 = time.perf_counter()
        train, test = simulate(e, work)
        schedule = train.with_suffix(".schedule.toml")
        scores, models = [], []
        tr, te = load_runs([str(train)], quiet=True), load_runs([str(test)], quiet=True)
        for name, extra in COLUMNS + PLATEAUS:
            model = work / f"{e.name}-{name.replace(', ', '-').replace(' ', '-')}"
            reused = reuse and (model / "manifest.json").exists()
            if not reused and not train_quietly(train, schedule, model, extra):
                print(f"{e.name}: training ({name}) failed")
                return 2
            models.append(model)
        scores = [held_out(m, tr, te, guard=False, noise=e.noise) for m in models[:len(COLUMNS)]]
        scores += [held_out(models[c], tr, te, guard=True, noise=e.noise) for _, c in GUARDED]
        scores += [held_out(m, tr, te, guard=True, noise=e.noise) for m in models[len(COLUMNS):]]
        sched = load_schedule(schedule)
        base = baseline_eps(tr, te, sched, "yB")
        print(f"\n{e.name} (seed {e.seed}, schedule {e.schedule}, noise x{e.noise:g}; "
              f"{time.perf_counter() - t0:.0f} s)")
        labels = LABELS
        print("| OC | " + " | ".join(labels) + " | today's default's model | curve | floor |")
        print("|---|" + "---|" * (len(labels) + 3))
        for k, (oc, b) in enumerate(zip([s[0] for s in scores[0]], base)):
            eps = [col[k][1] for col in scores]
            kind, low = scores[-1][k][2], scores[-1][k][3]  # today's default's model
            print(f"| {oc} | " + " | ".join(f"{v:.3f}" for v in eps) + f" | {kind} | {b:.3f} | {low:.3f} |")
            rows.append((e.name, k, oc, eps, b, kind, low, [col[k][4] for col in scores]))
        mine = np.array([r[3] + [r[4], r[6]] for r in rows if r[0] == e.name], dtype=float)
        m = np.nanmean(mine, axis=0)
        print("| mean | " + " | ".join(f"{v:.3f}" for v in m[:-2]) + f" | | {m[-2]:.3f} | {m[-1]:.3f} |",
              flush=True)
    print(f"\n{set_name} set: {len(engines)} engines, {len(rows)} OCs (8 training, 10 held-out runs each)")
    print("| | mean held-out eps_td | OCs worse than the curve by > 5 % | first OC after a start: "
          "mean | first OCs worse than the curve by > 5 % |")
    print("|---|---|---|---|---|")
    a = np.array([r[3] for r in rows], dtype=float)
    curve = np.array([r[4] for r in rows], dtype=float)
    first = np.array([r[1] == 0 for r in rows])
    for c, label in enumerate(LABELS):
        v, worse = a[:, c], a[:, c] > 1.05 * curve
        print(f"| {label} | {np.nanmean(v):.3f} | {int(worse.sum())} of {v.size} | "
              f"{np.nanmean(v[first]):.3f} | {int(worse[first].sum())} of {int(first.sum())} |")
    print(f"| characteristic curve | {np.nanmean(curve):.3f} | - | {np.nanmean(curve[first]):.3f} | - |")
    floor = np.array([r[6] for r in rows], dtype=float)
    print(f"| noise floor | {np.nanmean(floor):.3f} | - | {np.nanmean(floor[first]):.3f} | - |")
    labels = LABELS
    print("\nWhere the error above the noise floor lies (mean share over the OCs; ``excess_split``):")
    print(f"| | transition (first {RAMP_S:g} s of a visit) | the plateau's offset (a missed level) "
          "| the rest |")
    print("|---|---|---|---|")
    splits = np.array([r[7] for r in rows], dtype=float)  # (OCs, columns, 3)
    for c, label in enumerate(labels):
        share = np.nanmean(splits[:, c, :], axis=0)
        print(f"| {label} | " + " | ".join(f"{100 * v:.0f} %" for v in share) + " |")
    for held, new in ((0, 1), (2, 3), (0, 4), (2, 5), (0, 6), (2, 7), (4, 6), (5, 7), (0, 8), (2, 9),
                      (6, 8), (7, 9)):
        change = 100 * (np.nanmean(a[:, new]) / np.nanmean(a[:, held]) - 1)
        change_first = 100 * (np.nanmean(a[first, new]) / np.nanmean(a[first, held]) - 1)
        room = 100 * (np.nanmean(floor) / np.nanmean(a[:, held]) - 1)
        print(f"{labels[new]} against {labels[held]}: {change:+.1f} % (first OCs {change_first:+.1f} %; "
              f"the noise floor {room:+.1f} %)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
