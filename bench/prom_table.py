"""Table 6.1 on simulated engines: per OC, held-out eps_td of the parametric model,
generic WDMD, Delay-DMD, the characteristic curve and the default, which takes the parametric
model where its CV error is the lowest of all candidates (by the curve margin).

    python -m bench prom-table [--set report|dev|all] [--engines E14Ax1,...] [--workdir DIR]

Per engine of ``bench generalise`` (its simulated recordings: 8 training runs, the next 10
held out; kept in --workdir and reused), four trainings with ``ordervib train --target yB``:

* ``pROM``: ``--method prom --no-curve-candidates``: per OC the parametric model alone
  (``PROM_CANDIDATES``: a WDMD per training run, interpolated in pole-residue form to the
  run's engine-history value at the switch; parameter, levels and weights by CV),
* ``WDMD``, ``Delay-DMD``: ``--method wdmd|delay-dmd --no-curve-candidates --no-prom``: one
  model per OC over all runs (inputs by MS-DPCCA, hyper-parameters by CV),
* ``default``: ``ordervib train`` (every candidate: WDMD, the parametric models, the curves),

the characteristic curve (``baseline_eps``) beside. Each cell is the held-out eps_td (the
history carried through the training runs into the held-out ones, as a node that ran them
has it), the CV eps_td in brackets; the default's column names the model it chose.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.generalise import SETS, held_out, simulate, train_quietly

VARIANTS = {
    "pROM": {"method": "prom", "curves": False},
    "WDMD": {"method": "wdmd", "curves": False, "prom": False},
    "Delay-DMD": {"method": "delay-dmd", "curves": False, "prom": False},
    "default": {},
}


def _cv(model: Path) -> dict[str, float]:
    m = json.loads((model / "manifest.json").read_text())
    return {oc["name"]: float("nan") if oc.get("cv_eps") is None else float(oc["cv_eps"]) for oc in m["ocs"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench prom-table")
    ap.add_argument("--set", choices=[*SETS, "all"], default="report")
    ap.add_argument("--engines", default=None, help="engine names of the set, comma-separated (default: all)")
    ap.add_argument("--workdir", help="keep recordings and models here (default: a new temp folder)")
    args = ap.parse_args(argv)
    from node.contract.schedule import load_schedule
    from node.training.evaluation import baseline_eps
    from node.training.fit import load_runs

    work = Path(args.workdir or tempfile.mkdtemp(prefix="ordervib-prom-table-"))
    work.mkdir(parents=True, exist_ok=True)
    engines = SETS["dev"] + SETS["report"] if args.set == "all" else SETS[args.set]
    if args.engines:
        want = set(args.engines.split(","))
        engines = [e for e in engines if e.name in want]
    rows: list[list[float]] = []
    taken = 0
    prom_lowest = 0
    for e in engines:
        t0 = time.perf_counter()
        train, test = simulate(e, work)
        schedule = train.with_suffix(".schedule.toml")
        held: dict[str, dict[str, tuple[float, str]]] = {}
        cvs: dict[str, dict[str, float]] = {}
        tr, te = load_runs([str(train)], quiet=True), load_runs([str(test)], quiet=True)
        for name, extra in VARIANTS.items():
            model = work / f"{e.name}-{name.lower()}"
            if not train_quietly(train, schedule, model, extra):
                print(f"{e.name}: training ({name}) failed")
                return 2
            held[name] = {oc: (eps, kind) for oc, eps, kind, *_ in held_out(model, tr, te, guard=False)}
            cvs[name] = _cv(model)
        base = baseline_eps(tr, te, load_schedule(schedule), "yB")
        print(f"\n{e.name} (seed {e.seed}, schedule {e.schedule}, noise x{e.noise:g}; "
              f"{time.perf_counter() - t0:.0f} s)")
        print("| OC | pROM (CV) | WDMD (CV) | Delay-DMD (CV) | curve | default (CV) | default's model |")
        print("|---|---|---|---|---|---|---|")
        for oc, b in zip(held["default"], base):
            cells = []
            vals = []
            for name in ("pROM", "WDMD", "Delay-DMD"):
                eps = held[name].get(oc, (float("nan"), ""))[0]
                cells.append(f"{eps:.3f} ({cvs[name].get(oc, float('nan')):.3f})")
                vals.append(eps)
            d_eps, kind = held["default"][oc]
            taken += kind.startswith("prom")
            prom_lowest += cvs["pROM"].get(oc, np.inf) <= cvs["default"].get(oc, np.inf)
            d_cv = cvs["default"][oc]
            print(f"| {oc} | {' | '.join(cells)} | {b:.3f} | {d_eps:.3f} ({d_cv:.3f}) | {kind} |")
            rows.append([*vals, b, d_eps])
        mine = np.array(rows[-len(base):], dtype=float)
        m = np.nanmean(mine, axis=0)
        print(f"| mean | {m[0]:.3f} | {m[1]:.3f} | {m[2]:.3f} | {m[3]:.3f} | {m[4]:.3f} | |", flush=True)
    a = np.array(rows, dtype=float)
    print(f"\n{len(engines)} engines, {len(rows)} OCs: mean held-out eps_td")
    print("| pROM | WDMD | Delay-DMD | curve | default |")
    print("|---|---|---|---|---|")
    print("| " + " | ".join(f"{v:.3f}" for v in np.nanmean(a, axis=0)) + " |")
    print(f"pROM below the curve in {int(np.sum(a[:, 0] < a[:, 3]))} of {len(rows)} OCs, below the default "
          f"in {int(np.sum(a[:, 0] < a[:, 4]))}; its CV error the lowest of all candidates in {prom_lowest}; "
          f"the default took it in {taken}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
