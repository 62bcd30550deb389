"""The generated family of parametric systems (``harness.prom_family``): how often the default
``ParametricROM`` is no worse than the nearest sample's model, near a model fitted directly at
the judged parameter, and warns when it falls back.

    python -m bench prom-family [--cases 200] [--first 0] [--jobs 1]

Cases ``first`` .. ``first + cases - 1`` (seeded; kind and noise cycle with the seed). Prints the
distribution per class (crossing / veering / neither) and noise level and the pass fractions
beside the targets, apart for the seeds the validation's rules were chosen on
(``harness.prom_family.TUNED``) and the held-out ones.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext

import numpy as np

import node
from harness import prom_family as pf
from node.console.table import print_table


def _case(seed: int) -> pf.Result:
    logging.getLogger("node.sysid.parametric").setLevel(logging.ERROR)
    return pf.run_case(pf.make_case(seed))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench prom-family", description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=200, help="number of cases (default %(default)s)")
    ap.add_argument("--first", type=int, default=0, help="first seed (default %(default)s)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="cases run in parallel processes (default %(default)s)")
    args = ap.parse_args(argv)
    logging.getLogger("node.sysid.parametric").setLevel(logging.ERROR)
    t0 = time.perf_counter()
    cmd = "python -m bench prom-family " + " ".join(sys.argv[2:] if argv is None else argv)
    print(f"# Parametric ROM on a generated family ({cmd.strip()}; ordervib {node.__version__})\n")
    results = []
    seeds = range(args.first, args.first + args.cases)
    with ProcessPoolExecutor(args.jobs) if args.jobs > 1 else nullcontext() as pool:
        for r in (pool.map(_case, seeds) if pool is not None else map(_case, seeds)):
            results.append(r)
            rules = (("worse than nearest", r.not_worse), ("far from direct", r.near_direct),
                     ("silent fallback", r.honest))
            flags = [name for name, ok in rules if not ok]
            if flags:
                print(f"{r.case.label()}: rom {r.rom:.3g}, direct {r.direct:.3g}, nearest {r.nearest:.3g}: "
                      f"{', '.join(flags)}", flush=True)
    rows = []
    for kind in pf.KINDS:
        for noise in pf.NOISES:
            sub = [r for r in results if r.case.kind == kind and r.case.noise == noise]
            if not sub:
                continue
            f = pf.fractions(sub)
            ratio = np.array([r.rom / max(r.direct, 1e-12) for r in sub])
            rows.append([kind, f"{noise:.0%}", str(len(sub)), f"{np.median([r.rom for r in sub]):.2e}",
                         f"{np.median(ratio):.2f}", f"{np.percentile(ratio, 90):.2f}",
                         str(sum(r.fell_back for r in sub)), *(f"{v:.0%}" for v in f.values())])
    print_table(["class", "noise", "cases", "median eps_td", "median rom/direct", "90th pct rom/direct",
                 "fallbacks", "not worse than nearest", "within 2x or 0.05 of direct", "fallbacks warned"],
                rows, markdown=True, title="Per class and noise level")
    targets = [pf.TARGET_NEAREST, pf.TARGET_DIRECT, 1.0]
    tuned = [r for r in results if r.case.seed in pf.TUNED]
    held = [r for r in results if r.case.seed not in pf.TUNED]
    span = f"{pf.TUNED.start}-{pf.TUNED.stop - 1}"
    parts = [(f"All {len(results)} cases", results)] + \
        ([(f"Seeds {span} ({len(tuned)}: the rules were chosen on these)", tuned),
          (f"The other {len(held)} seeds (held out)", held)] if tuned and held else [])
    for title, sub in parts:
        f = pf.fractions(sub)
        counts = [sum(r.not_worse for r in sub), sum(r.near_direct for r in sub), sum(r.honest for r in sub)]
        print_table(["rule", "pass fraction", "target"],
                    [[k, f"{v:.1%} ({c}/{len(sub)})", f">= {t:.0%}"]
                     for (k, v), c, t in zip(f.items(), counts, targets)], markdown=True, title=title)
    if not held:
        print(f"\n(every seed here is one the rules were chosen on: {span})")
    elif not tuned:
        print(f"\n(every seed here is held out: the rules were chosen on {span})")
    print(f"\nTotal benchmark time: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
