"""The files of a prediction: the planned profile CSV read (``read_profile``), the predicted
orders written as CSV rows (``write_csv``) to an open text stream; with acceptance limits, each
target's limit in force and its ``p_exceed`` too (``node.training.prediction_limits``)."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from typing import TextIO

import numpy as np

from node.contract.errors import OrdervibError
from node.contract.schedule import Limit
from node.runtime.history import HISTORY_CHANNELS
from node.training.prediction import Prediction, Profile
from node.training.prediction_limits import LIMIT_RULE, exceed_probability, limits_along
from node.training.prediction_reach import MARK_WORDS, finite_speeds

_NAN = math.nan


# -- the planned profile ---------------------------------------------------------------------------
def read_profile(path: str, switch: str) -> Profile:
    """A profile CSV: a header with ``t`` (s) and the switch channel (rpm), optionally any other
    channels, then one row of numbers per breakpoint. Every problem is a one-line
    OrdervibError naming the file (and line): unreadable, no header, a missing column, a
    repeated one, an empty cell, NaN or a non-number, a time that does not increase, fewer
    than two rows."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:  # (a spreadsheet's byte-order mark)
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise OrdervibError(f"profile {path}: not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise OrdervibError(f"profile {path}: cannot be read ({exc})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise OrdervibError(f"profile {path}: empty (needs a header with t and {switch})")
    header = [c.strip() for c in rows[0]]
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise OrdervibError(f"profile {path}: column(s) {', '.join(dup)} repeated")
    for need in ("t", switch):
        if need not in header:
            raise OrdervibError(f"profile {path}: no column {need!r} (has {', '.join(header)}); "
                                f"a profile needs t (s) and {switch} (rpm)")
    values = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:]):
        line = i + 2
        if len(row) != len(header):
            raise OrdervibError(f"profile {path} line {line}: {len(row)} values for {len(header)} columns")
        for j, cell in enumerate(row):
            try:
                v = float(cell)
            except ValueError:
                raise OrdervibError(f"profile {path} line {line}: {header[j]} {cell.strip()!r} "
                                    "is not a number") from None
            if not math.isfinite(v):
                raise OrdervibError(f"profile {path} line {line}: {header[j]} is {cell.strip()} "
                                    "(every value must be a finite number)")
            if header[j] == switch and (why := finite_speeds(np.array([v]))) is not None:
                raise OrdervibError(f"profile {path} line {line}: {switch} {why}")
            values[i, j] = v
    if values.shape[0] < 2:
        raise OrdervibError(f"profile {path}: {values.shape[0]} row(s), needs at least two")
    t = values[:, header.index("t")]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise OrdervibError(f"profile {path} line {k + 2}: time {t[k]:g} s does not increase "
                            f"(the row before has {t[k - 1]:g} s)")
    cols = [j for j, c in enumerate(header) if c != "t"]
    return Profile(t, values[:, cols], tuple(header[j] for j in cols), switch)


# -- output ---------------------------------------------------------------------------------------
def csv_columns(preds: Sequence[Prediction], limits: Sequence[Limit] = ()) -> list[str]:
    """The columns ``write_csv`` writes: the stated history's label, time, OC, where the plan
    leaves what the model knows (``outside``: empty inside, ``speed`` beyond the training runs'
    speeds, ``no_oc`` held at a speed no OC has; ``node.training.prediction_reach``), each target
    predicted with its interval and its model's envelope (``yB``, ``yB_lo``, ``yB_hi``,
    ``yB_envelope``: the node's monitor-message field, above 1 where the model's inputs, the
    engine history among them, left its training region), the engine-history channels, and
    every input fed to the node. With ``limits``, each target's limit in force and the
    probability that the sample exceeds it follow its envelope (``yB_limit``, ``yB_p_exceed``)."""
    p = preds[0]
    extra = ("_limit", "_p_exceed") if limits else ()
    per_target = (c for tg in p.targets for c in (tg, f"{tg}_lo", f"{tg}_hi", f"{tg}_envelope",
                                                   *(tg + e for e in extra)))
    return ["history", "t", "oc", "outside", *per_target, *HISTORY_CHANNELS, *p.channels]


def csv_notes(preds: Sequence[Prediction], limits: Sequence[Limit] = ()) -> list[str]:
    """The notes ``write_csv`` puts above the header (without their "# "): where the plan leaves
    what the model knows (``Prediction.reach_note``), the bounds and where they acted, where a
    model left its training region (``Prediction.envelope_notes``), the interval, the limits
    (when given) and how each filled channel was filled."""
    p = preds[0]
    out = []
    for q in preds:
        note = q.reach_note()
        if note is not None:
            at = f" ({q.label} h stood)" if len(preds) > 1 and q.label else ""
            out.append(f"outside{at}: {note}")
    out.append(f"bounds: {p.bound_rule}")
    for q in preds:
        at = f" ({q.label} h stood)" if len(preds) > 1 and q.label else ""
        out += [f"bounds acted{at}: {line}" for line in q.bound_notes()]
    for q in preds:
        at = f" ({q.label} h stood)" if len(preds) > 1 and q.label else ""
        out += [f"envelope{at}: {line}" for line in q.envelope_notes()]
    out.append(f"interval: {', '.join(f'{tg}_lo..{tg}_hi' for tg in p.targets)}: {p.interval_rule}")
    if limits:
        out.append("limits: " + "; ".join(f"{lim.target} {lim.where()}: {lim.max:g}" for lim in limits)
                   + f"; {LIMIT_RULE}")
    for how in dict.fromkeys(p.filled_how.values()):
        mine = [c for c, h in p.filled_how.items() if h == how]
        out.append(f"filled {', '.join(mine)}: {how}")
    if p.filled_own:
        out.append("filled from the OC's own curve: " + ", ".join(
            f"{c} {100 * v:.0f} %" for c, v in p.filled_own.items()) + " of the samples")
    if not p.filled_how:
        out.append("filled: none (the profile holds every channel the model takes)")
    return out


def write_csv(preds: Sequence[Prediction], f: TextIO, limits: Sequence[Limit] = ()) -> int:
    """Rows of each prediction (one per stated history) into ``f``; returns the rows written.
    limits: the acceptance limits (none: no limit columns, no limit note).

    Lines starting with "# " come first (``csv_notes``: read with a CSV reader that skips
    comments, e.g. pandas' ``comment="#"``), then the header (``csv_columns``). ``history``:
    each prediction's label (``ordervib predict``: the hours the engine stood before the
    profile as stated); numbers with 6 significant digits, NaN as an empty cell."""
    for line in csv_notes(preds, limits):
        f.write(f"# {line}\n")
    w = csv.writer(f, lineterminator="\n")
    w.writerow(csv_columns(preds, limits))
    n = 0
    for p in preds:
        names = [p.oc_names[i] if i >= 0 else "" for i in p.oc.tolist()]
        marks = [MARK_WORDS[m] for m in p.marks.tolist()] if p.marks.shape == p.t.shape else [""] * p.t.size
        env = p.envelope if p.envelope.shape == p.predicted.shape else np.full(p.predicted.shape, _NAN)
        cols = [p.predicted, p.lo, p.hi, env]
        if limits:
            limit = limits_along(p, limits)
            cols += [limit, exceed_probability(p.predicted, p.hi, limit, p.level)]
        band = np.stack(cols, axis=2).reshape(p.t.size, -1)
        body = np.column_stack([band, p.history, p.inputs])
        for k in range(p.t.size):
            w.writerow([p.label, f"{p.t[k]:.3f}", names[k], marks[k], *map(_g, body[k].tolist())])
        n += p.t.size
    return n


def _g(x: float) -> str:
    return "" if x != x else f"{x:.6g}"
