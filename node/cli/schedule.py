"""``ordervib schedule infer``: propose a pass-off schedule from the plateaus in recordings."""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

import numpy as np

from node.cli.outputs import check_output, replacing
from node.contract import FS

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from node.training.runs import Run

log = logging.getLogger(__name__)

NAME = "schedule"
HELP = "schedule tools: 'infer' proposes a schedule from the speed plateaus found in recordings"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=["infer"], help="infer: print a schedule TOML")
    p.add_argument("recordings", nargs="+", metavar="REC.mcap")
    p.add_argument("--switch", default="nB", help="speed channel that defines the OCs (default nB)")
    p.add_argument("--tolerance", type=float, default=0.02,
                   help="relative band of a steady plateau (default 0.02)")
    p.add_argument("--min-plateau", type=float, default=5.0, metavar="S",
                   help="shortest plateau that counts, seconds (default 5)")
    p.add_argument("--out", default=None, metavar="S.toml", help="write here instead of stdout")


def find_plateaus(speed: np.ndarray, tol: float, min_len: int, fs: float = FS) -> list[float]:
    """Mean speeds of the stretches (at least ``min_len`` samples) where the 0.5 s smoothed
    speed changes by less than a tenth of the band per 0.5 s, split where the level moves."""
    from node.training.dataset import fill_gaps
    s = fill_gaps(speed[:, None])[:, 0]
    k = max(1, int(0.5 * fs))
    s = np.convolve(s, np.ones(k) / k, mode="same")
    flat = np.zeros(s.size, dtype=bool)
    flat[k:] = np.abs(s[k:] - s[:-k]) < 0.1 * tol * np.maximum(np.abs(s[k:]), 1.0)
    out, i = [], 0
    while i < s.size:
        if not flat[i]:
            i += 1
            continue
        j = i
        while j < s.size and flat[j] and abs(s[j] - s[i]) <= 0.5 * tol * abs(s[i]):
            j += 1
        if j - i >= min_len:
            out.append(float(np.mean(s[i:j])))
        i = j
    return out


def ids_in_run(plats: list[float], levels: list[list[float]], tol: float) -> list[int]:
    """Plateau ids of a run's plateaus, in the run's order."""
    out = []
    for sp in plats:
        ids = [i for i, lv in enumerate(levels) if abs(np.mean(lv) - sp) <= tol * sp]
        if ids:
            out.append(min(ids, key=lambda i: abs(np.mean(levels[i]) - sp)))
    return out


def infer(runs: list[Run], switch: str, tol: float, min_len: int) -> Schedule:
    """The schedule of the plateaus seen in at least half the runs, in test order."""
    from node.contract.errors import OrdervibError
    from node.contract.schedule import OperatingCondition, Schedule
    levels: list[list[float]] = []  # per distinct plateau: speeds seen
    sequences: list[list[int]] = []
    top = max(float(np.nanmax(r.column(switch))) for r in runs if switch in r.channels)
    for r in runs:
        if switch not in r.channels:
            raise OrdervibError(f"a run has no {switch!r} channel")
        seen: set[int] = set()
        plats = find_plateaus(r.column(switch), tol, min_len)
        plats = [p for p in plats if p > 0.3 * top]  # idle and starting are not OCs
        for sp in plats:
            match = next((i for i, lv in enumerate(levels)
                          if abs(np.mean(lv) - sp) <= tol * sp and i not in seen), None)
            if match is None:
                levels.append([sp])
                match = len(levels) - 1
            else:
                levels[match].append(sp)
            seen.add(match)
        sequences.append(list(dict.fromkeys(ids_in_run(plats, levels, tol))))
    if not levels:
        raise OrdervibError("no speed plateau found in the recordings")
    need = max(1, len(runs) // 2)
    keep = [i for i in range(len(levels)) if len(levels[i]) >= need]
    # the order of the run that saw most of them; each other plateau goes right after the
    # latest plateau seen before it in some run (runs that missed plateaus see earlier ones)
    ref = max(sequences, key=lambda seq: len([i for i in seq if i in keep]))
    order = [i for i in ref if i in keep]
    missing = [i for i in keep if i not in order]
    while missing:
        i = max(missing, key=lambda j: len(levels[j]))
        missing.remove(i)
        before = [seq[:seq.index(i)] for seq in sequences if i in seq]
        latest = [next((j for j in reversed(b) if j in order), None) for b in before]
        preds = [j for j in latest if j is not None]
        at = max(order.index(j) for j in preds) + 1 if preds else 0
        order.insert(at, i)
    ocs = tuple(OperatingCondition(f"OC{k + 1}", round(float(np.mean(levels[i])), 1))
                for k, i in enumerate(order))
    return Schedule(ocs, switch, tol)


def run(args: argparse.Namespace) -> int:
    from node.training.fit import load_runs
    if args.out:
        check_output(args.out, "--out", inputs=args.recordings)
    runs = load_runs(args.recordings, quiet=True)
    schedule = infer(runs, args.switch, args.tolerance, int(args.min_plateau * FS))
    text = "# proposed by ordervib schedule infer: check names and order\n" + schedule.to_toml()
    if args.out:
        with replacing(args.out) as tmp, open(tmp, "w") as f:
            f.write(text)
        log.info("schedule with %d OCs written to %s", len(schedule.ocs), args.out)
    else:
        print(text)
    return 0
