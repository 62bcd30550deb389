"""Study: averages of an OC's best candidates, the dynamic model among them, against
the default.

    python -m bench top-curves [--set dev|report|all] [--workdir DIR]

Per engine of ``bench generalise``'s sets (8 training, 10 held-out runs; recordings kept and
reused in --workdir), yB is trained as ``ordervib train`` trains it, in one process and with
the full CV (every candidate on every fold). Where the default's model is a curve or an
average, two rules are applied on the training runs alone, from the leave-one-run-out CV
predictions (averaged: an average's CV):

* ``top``: the k best of the pool (the 3 best curves and the grid's best model, a WDMD),
  ranked by CV eps, k in 1-3 by the CV eps of their average;
* ``subset``: the subset of that pool (size 1-3) whose average has the lowest CV eps.

They were measured against the former default (averages of the 2-3 best curves
alone; development engines 0.1405, top 0.1366, subset 0.1385) and made ``top`` the default
(``node.training.train``'s average of the best): since then its column reproduces the default's.

Per OC it prints the held-out eps_td of the default and of both alternatives (with their
members) beside the characteristic curve, then the means and the OCs worse than the curve by
> 5 %. This is a study, not the product: it reads the CV's predictions by wrapping
``node.training.train.cross_validate_candidate``.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from bench.generalise import engine_args, simulate
from node.models.kinds import fit_oc_model
from node.models.ocmodel import Method
from node.runtime.history import HISTORY_CHANNELS
from node.sysid.metrics import pooled_eps
from node.training import train as T
from node.training.ocdata import OCData

Pairs = list[tuple[np.ndarray, np.ndarray]]
Member = tuple[str, dict, Pairs]  # method, params, CV pairs


def _key(method: str, params: dict) -> tuple[str, str]:
    return str(method), repr(sorted(params.items()))


class CVSpy:
    """Keeps every CV's (measured, predicted) pairs per OC while installed."""

    def __init__(self) -> None:
        self.seen: dict[str, tuple[OCData, dict[tuple[str, str], tuple[str, dict, Pairs]]]] = {}
        self._cv = T.cross_validate_candidate

    def __enter__(self) -> CVSpy:
        def spy(d, folds, method, params, fold_inputs, bound=float("inf"), parts=True):  # type: ignore[no-untyped-def]
            score, pairs = self._cv(d, folds, method, params, fold_inputs, bound, parts)
            self.seen.setdefault(d.name, (d, {}))[1][_key(method, params)] = (str(method), params, pairs)
            return score, pairs
        T.cross_validate_candidate = spy  # type: ignore[assignment]
        return self

    def __exit__(self, *exc: object) -> None:
        T.cross_validate_candidate = self._cv


def _avg_eps(members: tuple[Member, ...]) -> float:
    k = len(members)
    return pooled_eps([(y, sum(m[2][n][1] for m in members) / k) for n, (y, _) in enumerate(members[0][2])])


def pool(d: OCData, seen: dict[tuple[str, str], tuple[str, dict, Pairs]], method: str) -> list[Member]:
    """The 3 CV-best curves and the grid's CV-best model, best first."""
    def ranked(keep: object) -> list[Member]:
        out = [(m, p, pr) for m, p, pr in seen.values() if pr and keep(m) and np.isfinite(pooled_eps(pr))]
        return sorted(out, key=lambda x: pooled_eps(x[2]))
    curves = ranked(lambda m: m == Method.CURVE.value)[:3]
    grid = ranked(lambda m: m == str(method))[:1]
    return sorted(curves + grid, key=lambda x: pooled_eps(x[2]))


def choose(members: list[Member], subsets: bool) -> tuple[Member, ...]:
    """top: the k best (k 1-3) whose average has the lowest CV eps; subsets: any 1-3 of them."""
    if subsets:
        cands = [c for k in (1, 2, 3) for c in itertools.combinations(members, k)]
    else:
        cands = [tuple(members[:k]) for k in (1, 2, 3) if k <= len(members)]
    return min(cands, key=_avg_eps)


def main(argv: list[str] | None = None) -> int:
    work, _, engines, _ = engine_args("top-curves", "dev", argv)
    from node.contract.schedule import load_schedule
    from node.training.dataset import with_history
    from node.training.evaluation import baseline_eps, predict_segments
    from node.training.fit import load_runs

    modes = ("top", "subset")
    rows = []
    for e in engines:
        trp, tep = simulate(e, work)
        sched = load_schedule(trp.with_suffix(".schedule.toml"))
        tr, te = load_runs([str(trp)], quiet=True), load_runs([str(tep)], quiet=True)
        fleet = T.fleet_curve(tr, sched.switch, "yB")
        config = T.history_config(tr, sched)
        with CVSpy() as spy:
            res = T.train(tr, sched, fleet=fleet, config=config, workers=1, prune=False)
        base = baseline_eps(tr, te, sched, "yB")
        if any(c in HISTORY_CHANNELS for r in res for c in r.inputs):
            te = with_history(tr + te, sched, config)[len(tr):]
        chosen = predict_segments(res, te, sched, "yB", fleet, config)
        results = {}
        for mode in modes:
            members: dict[str, list] = {}
            for r in res:
                if r.model is None or r.name not in spy.seen or not r.kind.startswith(("curve", "average")):
                    continue
                d, seen = spy.seen[r.name]
                rows_all = list(range(len(d.runs)))
                members[r.name] = []
                for meth, params, _ in choose(pool(d, seen, "wdmd"), mode == "subset"):
                    if meth == Method.CURVE.value:
                        inputs = T.curve_model_inputs(d, params) or []
                    else:
                        inputs = T.select_inputs(d, rows_all, None, 4)[0]
                    model = fit_oc_model(meth, params, T.oc_trajectories(d, rows_all, inputs))
                    members[r.name].append(dataclasses.replace(r, model=model, inputs=inputs, params=params))
            layers = [predict_segments([m[i] if len(m := members.get(r.name, [])) > i else r for r in res],
                                       te, sched, "yB", fleet, config)
                      for i in range(max((len(v) for v in members.values()), default=1))]
            results[mode] = (members, layers)
        for j, name in enumerate(sched.names):
            mine = [p for p in chosen if p.oc == j]
            if not mine:
                continue
            row, text = [pooled_eps([(p.measured, p.predicted) for p in mine])], []
            for mode in modes:
                members, layers = results[mode]
                k = max(1, len(members.get(name, [])))
                lay = [[q for q in layers[i] if q.oc == j] for i in range(k)]
                row.append(pooled_eps([(p.measured, sum(lay[i][n].predicted for i in range(k)) / k)
                                       for n, p in enumerate(mine)]))
                text.append("+".join(str(m.params.get("variant", m.model.method.value))
                                     for m in members.get(name, [])) or "-")
            kind = next(r.kind for r in res if r.name == name)
            rows.append((*row, base[j]))
            print(f"{e.name} {name:5s} {kind:36s} default {row[0]:.3f} top {row[1]:.3f} ({text[0]}) "
                  f"subset {row[2]:.3f} ({text[1]}) curve {base[j]:.3f}", flush=True)
    arr = np.array(rows, float)
    print(f"\n{len(rows)} OCs: mean held-out eps_td default {arr[:, 0].mean():.4f}, "
          f"top {arr[:, 1].mean():.4f}, subset {arr[:, 2].mean():.4f}, "
          f"characteristic curve {arr[:, 3].mean():.4f}")
    for i, name in ((0, "default"), (1, "top"), (2, "subset")):
        print(f"{name}: OCs worse than the curve by > 5 %: {int((arr[:, i] > 1.05 * arr[:, 3]).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
