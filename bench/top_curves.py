"""Issue 13 study: the average of the CV-best curve candidates of an OC against the default.

    python -m bench top-curves [--set dev|report|all] [--workdir DIR]

Per engine of ``bench generalise``'s sets (8 training, 10 held-out runs; recordings kept and
reused in --workdir), yB is trained as ``ordervib train`` trains it, in one process and with
the full CV (every curve candidate on every fold). Where an OC's model is a curve, the
average of its k best curve candidates is taken instead when its leave-one-run-out CV eps
(the candidates' own CV predictions averaged) is lower, k in 1, 2, 3: a choice made on the
training runs alone; and again with members that predict what the best does only (the
amplitude, or the 1x vector: ``same level``). Per OC it prints the held-out eps_td of the
default and of both averages (with their members) beside the characteristic curve, then the
means and the OCs worse than the curve by > 5 %.

This is a study, not the product: it reads the CV's predictions by wrapping
``node.training.train._cross_validate``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.generalise import engine_args, simulate
from node.models.curve import Variant
from node.models.kinds import fit_oc_model
from node.models.ocmodel import Method
from node.runtime.history import HISTORY_CHANNELS
from node.sysid.metrics import pooled_eps
from node.training import train as T

Pairs = list[tuple[np.ndarray, np.ndarray]]


def _key(method: str, params: dict) -> tuple[str, str]:
    return str(method), repr(sorted(params.items()))


class CVSpy:
    """Keeps every CV's (measured, predicted) pairs per OC while installed."""

    def __init__(self) -> None:
        self.seen: dict[str, tuple[T.OCData, dict[tuple[str, str], Pairs]]] = {}
        self._cv = T._cross_validate

    def __enter__(self) -> CVSpy:
        def spy(d, folds, method, params, fold_inputs, bound=float("inf"), parts=True):  # type: ignore[no-untyped-def]
            score, pairs = self._cv(d, folds, method, params, fold_inputs, bound, parts)
            self.seen.setdefault(d.name, (d, {}))[1][_key(method, params)] = pairs
            return score, pairs
        T._cross_validate = spy  # type: ignore[assignment]
        return self

    def __exit__(self, *exc: object) -> None:
        T._cross_validate = self._cv


def average_members(d: T.OCData, pairs: dict[tuple[str, str], Pairs], k_max: int = 3,
                    same_level: bool = False) -> list[dict]:
    """The curve candidates whose average has the lowest CV eps (the best alone included);
    same_level: only those that predict what the best does (the amplitude, or the 1x vector)."""
    cands = sorted(((pooled_eps(p), c, p) for c in d.curves if (p := pairs.get(_key(Method.CURVE, c)))),
                   key=lambda x: x[0])
    if not cands:
        return []
    if same_level:
        vector = Variant(cands[0][1]["variant"]).on_vector
        cands = [x for x in cands if Variant(x[1]["variant"]).on_vector == vector]
    best_k, best = 1, cands[0][0]
    for k in range(2, min(k_max, len(cands)) + 1):
        avg = [(y, sum(cands[i][2][n][1] for i in range(k)) / k) for n, (y, _) in enumerate(cands[0][2])]
        if (score := pooled_eps(avg)) < best:
            best_k, best = k, score
    return [c for _, c, _ in cands[:best_k]]


def main(argv: list[str] | None = None) -> int:
    work, _, engines = engine_args("top-curves", "dev", argv)
    from node.cli.train import load_runs
    from node.contract.schedule import load_schedule
    from node.training.dataset import with_history
    from node.training.evaluation import baseline_eps, predict_segments

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
        for mode in (False, True):  # any members; members of the best's level only
            members: dict[str, list] = {}
            for r in res:
                if r.model is None or r.name not in spy.seen or not r.kind.startswith("curve"):
                    continue
                d, pairs = spy.seen[r.name]
                rows_all = list(range(len(d.runs)))
                members[r.name] = []
                for c in average_members(d, pairs, same_level=mode):
                    inputs = T._curve_inputs(d, c) or []
                    model = fit_oc_model(Method.CURVE, c, T._trajs(d, rows_all, inputs))
                    members[r.name].append(dataclasses.replace(r, model=model, inputs=inputs, params=c))
            layers = [predict_segments([m[i] if len(m := members.get(r.name, [])) > i else r for r in res],
                                       te, sched, "yB", fleet, config)
                      for i in range(max((len(v) for v in members.values()), default=1))]
            results[mode] = (members, layers)
        for j, name in enumerate(sched.names):
            mine = [p for p in chosen if p.oc == j]
            if not mine:
                continue
            row, text = [pooled_eps([(p.measured, p.predicted) for p in mine])], []
            for mode in (False, True):
                members, layers = results[mode]
                k = max(1, len(members.get(name, [])))
                lay = [[q for q in layers[i] if q.oc == j] for i in range(k)]
                row.append(pooled_eps([(p.measured, sum(lay[i][n].predicted for i in range(k)) / k)
                                       for n, p in enumerate(mine)]))
                text.append("+".join(m.params["variant"] for m in members.get(name, [])) or "-")
            kind = next(r.kind for r in res if r.name == name)
            rows.append((*row, base[j]))
            print(f"{e.name} {name:5s} {kind:16s} default {row[0]:.3f} average {row[1]:.3f} ({text[0]}) "
                  f"same level {row[2]:.3f} ({text[1]}) curve {base[j]:.3f}", flush=True)
    arr = np.array(rows, float)
    print(f"\n{len(rows)} OCs: mean held-out eps_td default {arr[:, 0].mean():.4f}, "
          f"average {arr[:, 1].mean():.4f}, same level {arr[:, 2].mean():.4f}, "
          f"characteristic curve {arr[:, 3].mean():.4f}")
    for i, name in ((0, "default"), (1, "average"), (2, "same level")):
        print(f"{name}: OCs worse than the curve by > 5 %: {int((arr[:, i] > 1.05 * arr[:, 3]).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
