"""Issue 15 study: do stiffness losses stand out of a plateau's normal vector drift, with or
without the slow temperatures' share of it removed?

    python -m bench stiffness-drift [--workdir W] [--seeds 14,15,16]

On ``bench faults``'s recordings in W (``engine{seed}/``: training runs, normal held-out runs,
``stiffness-{1,2,3}.mcap`` with their truth), per steady plateau (after 3 s of settling) the
order's 1x vector minus its mean over the plateau's first 4 s (the anchored vector check's
reference), as a 1 s mean over the noise of a 1 s mean (the training runs' first differences
per OC): ``raw``. ``comp``: the same after removing a per-OC complex gain times the change of
the slow temperatures (tF, tI, tH) since that reference, the gains by least squares over the
training runs' plateaus. Per stiffness onset it prints the largest statistic within 60 s of
the onset over the largest of any normal held-out plateau of the same OC: beyond 1, a drift
rule with no false alarm on those runs could flag it in time. A study, not the product.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from node.contract import FS, Phase
from node.contract.schedule import Schedule, load_schedule
from node.mcap import Run, read_runs
from node.models.config import RuntimeConfig
from node.runtime.ocdetect import OCDetector
from node.training.dataset import fill_gaps, target_vectors

TEMPS = ["tF", "tI", "tH"]
CH = ["nB", "yB", "yB_ph", *TEMPS]
SETTLE, LONG, SHORT = int(3 * FS), int(4 * FS), int(1 * FS)

def plateaus(run: Run, sched: Schedule) -> list[tuple[int, int, int]]:
    """(oc, first, last sample) of each steady plateau."""
    det = OCDetector(sched, RuntimeConfig(), FS)
    sp = run.column("nB")
    out: list[tuple[int, int, int]] = []
    cur: list[int] | None = None
    for k, v in enumerate(sp.tolist()):
        st = det.step(v)
        if st.phase is Phase.STEADY:
            if cur is None:
                cur = [int(st.oc), k, k]
            cur[2] = k
        elif cur is not None:
            out.append((cur[0], cur[1], cur[2]))
            cur = None
    if cur is not None:
        out.append((cur[0], cur[1], cur[2]))
    return out

def plateau_data(run: Run, sched: Schedule) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """Per plateau: oc, first sample after settling, the vector and temperatures from their reference."""
    z = target_vectors(run, "yB")  # amplitude and phase held over gaps, as training holds them
    if z is None:
        raise SystemExit("the recordings hold no yB_ph: simulate them with the phase channels")
    T = fill_gaps(np.column_stack([run.column(c) for c in TEMPS]))
    for oc, a, b in plateaus(run, sched):
        a0 = a + SETTLE
        if b - a0 < LONG + SHORT:
            continue
        zr = z[a0:b + 1] - np.nanmean(z[a0:a0 + LONG])
        Tr = T[a0:b + 1] - np.nanmean(T[a0:a0 + LONG], axis=0)
        yield oc, a0, zr, Tr

def fit_gains(items: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Complex gains (m,) of the temperature changes on the vector change, least squares."""
    X = np.vstack([Tr for Tr, _ in items])
    Z = np.concatenate([zr for _, zr in items])
    ok = np.isfinite(Z) & np.isfinite(X).all(axis=1)
    X, Z = X[ok], Z[ok]
    Xs = X.std(axis=0) + 1e-12
    g: np.ndarray = np.linalg.lstsq(X / Xs, Z, rcond=None)[0] / Xs
    return g

def stat(zr: np.ndarray, Tr: np.ndarray, g: np.ndarray | None, noise: float) -> np.ndarray:
    """|1 s mean of the drift (less the temperatures' share)| over the noise of a 1 s mean."""
    r = zr - Tr @ g if g is not None else zr
    m = np.convolve(np.nan_to_num(r), np.ones(SHORT) / SHORT, mode="same")
    out: np.ndarray = np.abs(m) / noise
    return out

def study(work: Path, engines: list[int]) -> int:
    rows = []
    for e in engines:
        W = work / f"engine{e}"
        sched = load_schedule(W / "train.schedule.toml")
        train = read_runs(W / "train.mcap", CH)
        by_oc: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for r in train:
            for oc, _, zr, Tr in plateau_data(r, sched):
                by_oc.setdefault(oc, []).append((Tr, zr))
        gains = {oc: fit_gains(v) for oc, v in by_oc.items()}
        noise: dict[int, float] = {}
        for oc, v in by_oc.items():
            d = np.concatenate([np.diff(zr) for _, zr in v])
            d = d[np.isfinite(d)]
            noise[oc] = np.sqrt(np.mean(np.abs(d) ** 2) / 2) / np.sqrt(SHORT)  # sd of a 1 s mean
        normal = read_runs(W / "normal.mcap", CH)
        nmax: dict[tuple[int, str], float] = {}
        for r in normal:
            for oc, _, zr, Tr in plateau_data(r, sched):
                for mode, g in (("raw", None), ("comp", gains.get(oc))):
                    s = stat(zr, Tr, g, noise[oc]).max()
                    nmax[(oc, mode)] = max(nmax.get((oc, mode), 0.0), float(s))
        for i in (1, 2, 3):
            truth = json.loads((W / f"stiffness-{i}.truth.json").read_text())
            f = truth["runs"][-1]["fault"]
            run = read_runs(W / f"stiffness-{i}.mcap", CH)[-1]
            onset = f["onset"]
            res: dict[str, float] = {}
            for oc, a0, zr, Tr in plateau_data(run, sched):
                t = run.t[a0:a0 + len(zr)]
                win = (t >= onset) & (t <= onset + 60)
                if not win.any():
                    continue
                for mode, g in (("raw", None), ("comp", gains.get(oc))):
                    s = stat(zr, Tr, g, noise[oc])[win].max()
                    ratio = s / nmax.get((oc, mode), np.inf)
                    res[mode] = max(res.get(mode, 0.0), float(ratio))
            rows.append((e, i, f["oc"], res.get("raw", np.nan), res.get("comp", np.nan)))
            print(f"engine {e} stiffness-{i} onset {f['oc']}: fault drift / largest normal drift of its OC: "
                  f"raw {res.get('raw', float('nan')):.2f}, temperature-compensated "
                  f"{res.get('comp', float('nan')):.2f}", flush=True)
    a = np.array([(r[3], r[4]) for r in rows])
    print(f"onsets beyond every normal plateau of their OC: raw {int((a[:, 0] > 1).sum())}, compensated "
          f"{int((a[:, 1] > 1).sum())} of {len(rows)}")
    return 0



def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench stiffness-drift")
    ap.add_argument("--workdir", required=True, help="bench faults's work dir (its recordings)")
    ap.add_argument("--seeds", default="14,15,16")
    args = ap.parse_args(argv)
    return study(Path(args.workdir), [int(s) for s in args.seeds.split(",")])


if __name__ == "__main__":
    raise SystemExit(main())
