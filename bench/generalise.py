"""Held-out accuracy on engines the defaults were not chosen on (issue 13's judge).

    python -m bench generalise [--set report|dev|all] [--workdir DIR] [--engines LIST]

Each engine of the set is simulated by the project's simulator (its own seed: its own
rotor, imbalance and thermal history), with one of two schedules (A: the built-in 12 OCs;
B: ``harness/schedules/passoff_b.toml``, 9 OCs at other speeds, in another order, shorter
plateaus) and one of two noise levels (x1, x2.5): 8 training runs, then 10 held-out runs
of the same engine. Per engine and OC it prints the mean held-out eps_td of

* ``today``: ``ordervib train --no-curve-candidates --no-history --no-prom`` (WDMD with
  run_curve, the defaults before issue 13),
* ``no phase``: ``ordervib train --no-phase``: this version's defaults on the amplitudes alone,
* ``default``: ``ordervib train`` with this version's defaults (and which kind won the OC),
  which use the order's phase (the recordings carry it: ``yB_ph``),
* ``curve``: the characteristic-curve baseline,

all measured in this one run, then per set the mean and the OCs worse than the curve by
more than 5 %. The defaults were chosen on the ``dev`` engines only; ``report`` (the
default set) holds the others. Simulated recordings are kept in --workdir and reused.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness import make
from node.contract.errors import OrdervibError

SCHEDULE_B = Path(__file__).resolve().parents[1] / "harness" / "schedules" / "passoff_b.toml"


@dataclass(frozen=True)
class Engine:
    seed: int
    schedule: str  # "A" (built-in) or "B"
    noise: float

    @property
    def name(self) -> str:
        return f"E{self.seed}{self.schedule}x{self.noise:g}"


SETS = {
    "dev": [Engine(11, "A", 1.0), Engine(12, "A", 1.0), Engine(21, "B", 2.5), Engine(22, "A", 2.5),
            Engine(23, "B", 1.0), Engine(24, "B", 2.5), Engine(25, "A", 2.5)],
    "report": [Engine(14, "A", 1.0), Engine(15, "A", 1.0), Engine(16, "A", 1.0),
               Engine(31, "B", 1.0), Engine(32, "B", 1.0), Engine(33, "A", 2.5),
               Engine(34, "A", 2.5), Engine(35, "B", 2.5), Engine(36, "B", 2.5)],
}


def simulate(e: Engine, work: Path) -> tuple[Path, Path]:
    """The engine's 8 training and 10 held-out runs (reused when already there with the order
    phases; recordings from before the phase channels are simulated again)."""
    train, test = work / f"{e.name}-train.mcap", work / f"{e.name}-test.mcap"
    common = {"seed": e.seed, "noise_scale": e.noise,
              "schedule": str(SCHEDULE_B) if e.schedule == "B" else None}
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


def held_out(model: Path, train: Path, test: Path) -> list[tuple[str, float, str]]:
    """Per OC: (name, held-out eps_td, model kind), the history derived through the training
    runs first (as a node that ran them would have it)."""
    from node.models.bundle import load_bundle
    from node.runtime.history import HISTORY_CHANNELS
    from node.training.dataset import with_history
    from node.training.evaluation import evaluate
    from node.training.fit import load_runs

    b = load_bundle(model)
    tr, te = load_runs([str(train)], quiet=True), load_runs([str(test)], quiet=True)
    if any(c in HISTORY_CHANNELS for c in b.inputs):
        te = with_history(tr + te, b.schedule, b.config)[len(tr):]
    evals, _ = evaluate(b.ocs, te, b.schedule, b.target, b.curve, b.config)
    kinds = {r.name: r.kind for r in b.ocs}
    return [(e.name, e.eps, kinds[e.name]) for e in evals]


def engine_args(name: str, default_set: str, argv: list[str] | None) -> tuple[Path, str, list[Engine]]:
    """``--set`` and ``--workdir`` of a bench over these engines: the folder of the recordings
    (made), the set's name and its engines."""
    ap = argparse.ArgumentParser(prog=f"python -m bench {name}")
    ap.add_argument("--set", choices=[*SETS, "all"], default=default_set)
    ap.add_argument("--workdir", help="keep the simulated recordings here (default: a new temp folder)")
    args = ap.parse_args(argv)
    work = Path(args.workdir or tempfile.mkdtemp(prefix=f"ordervib-{name}-"))
    work.mkdir(parents=True, exist_ok=True)
    return work, args.set, SETS["dev"] + SETS["report"] if args.set == "all" else SETS[args.set]


def main(argv: list[str] | None = None) -> int:
    work, set_name, engines = engine_args("generalise", "report", argv)
    from node.contract.schedule import load_schedule
    from node.training.evaluation import baseline_eps
    from node.training.fit import load_runs

    rows: list[tuple[str, str, float, float, float, float, str]] = []
    for e in engines:
        t0 = time.perf_counter()
        train, test = simulate(e, work)
        schedule = train.with_suffix(".schedule.toml")
        scores = {}
        for name, extra in (("today", {"curves": False, "history": False, "prom": False}),
                            ("no-phase", {"phase": False}), ("default", {})):
            model = work / f"{e.name}-{name}"
            if not train_quietly(train, schedule, model, extra):
                print(f"{e.name}: training ({name}) failed")
                return 2
            scores[name] = held_out(model, train, test)
        sched = load_schedule(schedule)
        base = baseline_eps(load_runs([str(train)], quiet=True), load_runs([str(test)], quiet=True),
                            sched, "yB")
        print(f"\n{e.name} (seed {e.seed}, schedule {e.schedule}, noise x{e.noise:g}; "
              f"{time.perf_counter() - t0:.0f} s)")
        print("| OC | today | no phase | no phase's model | default | default's model | curve |")
        print("|---|---|---|---|---|---|---|")
        for (oc, today, _), (_, amp, amp_kind), (_, new, kind), b in zip(
                scores["today"], scores["no-phase"], scores["default"], base):
            print(f"| {oc} | {today:.3f} | {amp:.3f} | {amp_kind} | {new:.3f} | {kind} | {b:.3f} |")
            rows.append((e.name, oc, today, amp, new, b, kind))
        mine = np.array([r[2:6] for r in rows if r[0] == e.name], dtype=float)
        m = np.nanmean(mine, axis=0)
        print(f"| mean | {m[0]:.3f} | {m[1]:.3f} | | {m[2]:.3f} | | {m[3]:.3f} |", flush=True)
    a = np.array([r[2:6] for r in rows], dtype=float)
    a_curve = a[:, 3]
    print(f"\n{set_name} set: {len(engines)} engines, {len(rows)} OCs (8 training, 10 held-out runs each)")
    print("| | mean held-out eps_td | OCs worse than the curve by > 5 % |")
    print("|---|---|---|")
    for label, v in (("today", a[:, 0]), ("no phase", a[:, 1]), ("default (with phase)", a[:, 2])):
        print(f"| {label} | {np.nanmean(v):.3f} | {int(np.sum(v > 1.05 * a_curve))} of {v.size} |")
    print(f"| characteristic curve | {np.nanmean(a_curve):.3f} | - |")
    for label, v in (("no phase", a[:, 1]), ("default", a[:, 2])):
        print(f"{label} against today: {100 * (np.nanmean(v) / np.nanmean(a[:, 0]) - 1):+.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
