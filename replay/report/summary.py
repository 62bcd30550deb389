"""The report's summary, first on the page: per target, a verdict line and one compact table.

Per OC: the model's kind; eps_td of the model and of the characteristic curve on the same
samples for each run set (held-out, in-sample, unknown: ``node.training.provenance``), the
model's cell marked better or worse than the curve's; the CV eps_td; the share of samples
outside the training envelope (all runs); the node's alarm episodes. The numbers are panel
III's (``replay.report.panels.oc_scores`` over ``score_runs``), the verdict pools them as
``ordervib evaluate`` does (the mean of the OCs' eps_td).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

import numpy as np

from node.contract.schedule import Schedule
from node.models.bundle import Bundle
from replay.report.document import Block, Heading, Paragraph, Table
from replay.report.panels import Episode, OCScore, RunSet, Scores, oc_scores


def _f(x: float) -> str:
    return f"{x:.3f}" if np.isfinite(x) else "-"


def _means(scores: Sequence[OCScore]) -> tuple[float, float, int, int]:
    """Over the OCs the model scores: its mean eps_td, the curve's mean on them, how many OCs,
    in how many the model is below the curve (``ordervib evaluate``'s mean line)."""
    ok = [s for s in scores if np.isfinite(s.eps)]
    if not ok:
        return float("nan"), float("nan"), 0, 0
    curve = [s.curve_eps for s in ok if np.isfinite(s.curve_eps)]
    better = sum(1 for s in ok if np.isfinite(s.curve_eps) and s.eps < s.curve_eps)
    return (float(np.mean([s.eps for s in ok])), float(np.mean(curve)) if curve else float("nan"),
            len(ok), better)


def _run_sets(labels: Sequence[str], kinds: Sequence[str]) -> list[tuple[str, list[str]]]:
    """The provenances present, held-out first, each with its runs' labels."""
    from node.training.provenance import PROVENANCES

    return [(k, [lab for lab, x in zip(labels, kinds) if x == k]) for k in PROVENANCES if k in kinds]


def verdict(target: str, sets: Sequence[tuple[str, list[str], Sequence[OCScore]]],
            everything: Sequence[OCScore], episodes: Sequence[Episode]) -> tuple[str, str]:
    """The headline and the line of figures of one target: for each run set (provenance, run
    labels, its OC scores), the model's mean eps_td against the curve's; the alarm episodes;
    the share of samples outside the envelope over ``everything`` (all runs' OC scores).

    >>> s = [OCScore("OC1", "lasso", 1, 0.1, 0.9, 0.2, 0.5, 0.15, 0, 100, 5)]
    >>> head, line = verdict("yB", [("held-out", ["t #1"], s)], s, [])
    >>> head
    'yB: better than the characteristic curve on the held-out runs; no alarm'
    >>> line.split(". ")[0]
    "Held-out runs (t #1): mean eps_td 0.100 over 1 OCs against the curve's 0.200, better in 1 of 1"
    >>> head, line = verdict("yB", [("held-out", ["t #1"], s)], s, [Episode("t #1", "OC1", 3.0, 1.0, "step")])
    >>> head.split("; ")[1], line.split(". ")[-1]
    ('1 alarm episode(s)', '1 alarm episode(s), by reason step 1; by OC OC1 1.')
    >>> verdict("yB", [("in-sample", ["a #1"], s)], s, [])[0]
    'yB: no held-out run, the errors below are in-sample (CV eps_td estimates new runs); no alarm'
    """
    from node.training.provenance import HELD_OUT, IN_SAMPLE, TABLE_WORDS

    parts = []
    held = None
    for kind, labels, scores in sets:
        m, c, n, better = _means(scores)
        shown = ", ".join(labels[:4]) + (f" and {len(labels) - 4} more" if len(labels) > 4 else "")
        text = (f"{TABLE_WORDS[kind]} runs ({shown}): mean eps_td {_f(m)} over {n} OCs "
                f"against the curve's {_f(c)}, better in {better} of {n}")
        if kind == IN_SAMPLE:
            text += " (how the model fits its training data)"
        parts.append(text)
        if kind == HELD_OUT:
            held = (m, c)
    cv = [s.cv_eps for s in everything if np.isfinite(s.cv_eps)]
    if cv:
        parts.append(f"mean CV eps_td {np.mean(cv):.3f}")
    samples, outside = sum(s.samples for s in everything), sum(s.outside for s in everything)
    if samples:
        parts.append(f"{100.0 * outside / samples:.1f} % of the modelled samples outside the training "
                     "runs' envelope")
        guarded = sum(s.guarded for s in everything)
        parts.append(f"{100.0 * guarded / samples:.1f} % predicted with the characteristic curve (the "
                     "curve guard: where the model erred more so far in the OC)")
    if episodes:
        reasons = Counter(e.reason for e in episodes)
        where = Counter(e.oc for e in episodes)
        parts.append(f"{len(episodes)} alarm episode(s), by reason "
                     + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) + "; by OC "
                     + ", ".join(f"{oc} {v}" for oc, v in where.most_common(5))
                     + (" ..." if len(where) > 5 else ""))
    if held is None:
        head = "no held-out run, the errors below are in-sample (CV eps_td estimates new runs)"
    elif np.isfinite(held[0]) and np.isfinite(held[1]):
        head = ("better than" if held[0] < held[1] else "not better than") + \
            " the characteristic curve on the held-out runs"
    else:
        head = "no OC of the held-out runs scored"
    head += f"; {len(episodes)} alarm episode(s)" if episodes else "; no alarm"
    return f"{target}: {head}", " ".join(p[0].upper() + p[1:] + "." for p in parts)


def summary_blocks(bundle: Bundle, runs: RunSet, schedule: Schedule, target: str, scores: Scores,
                   episodes: Sequence[Episode]) -> list[Block]:
    """One target's summary: its verdict (a heading and a line of figures) and the per-OC table."""
    from node.training.provenance import TABLE_WORDS

    sets = [(kind, labels, oc_scores(bundle, schedule, *scores.of(kind)))
            for kind, labels in _run_sets(runs.labels, scores.kinds)]
    everything = oc_scores(bundle, schedule, scores.preds, scores.base)
    head, line = verdict(target, sets, everything, episodes)
    alarms = Counter(e.oc for e in episodes)
    rows, marks = [], []
    for j, oc in enumerate(schedule.segments):  # (the rundown last)
        res = bundle.oc(oc)
        if (res is None or res.model is None) and not any(s[j].segments for _, _, s in sets):
            continue
        row, mark = [oc, everything[j].kind], ["", ""]
        for _, _, s in sets:
            e, c = s[j].eps, s[j].curve_eps
            row += [_f(e), _f(c)]
            mark += ["better" if e < c else "worse" if e >= c else "", ""]
        n = alarms.get(oc, 0)
        row += [_f(everything[j].cv_eps), everything[j].outside_share, str(n)]
        mark += ["", "", "alarm" if n else ""]
        rows.append(row)
        marks.append(mark)
    header = ["OC", "model", *(h for _ in sets for h in ("model eps_td", "curve eps_td")),
              "CV eps_td", "outside the envelope", "alarm episodes"]
    groups = [("", 2), *((f"{TABLE_WORDS[k]} runs ({len(labels)})", 2) for k, labels, _ in sets), ("", 3)]
    caption = (f"{target} per OC: eps_td of the model and of the characteristic curve on the same samples "
               "per run set (green: the model's lower, red: not); outside the envelope and alarm episodes: "
               "all runs")
    return [Heading(head), Paragraph(line), Table(header, rows, caption, groups=groups, marks=marks)]
