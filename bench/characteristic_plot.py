"""Characteristic curve (yB against nB) of several simulated runs, to a PNG.

    .venv/bin/python -m bench.characteristic_plot [--recording REC.mcap]
        [--runs 6] [--seed 1] [--out docs/characteristic_curve.png]

Without --recording the runs are simulated in memory (full-length plateaus).
Needs matplotlib (installed with the ``peers`` extra, via pydmd).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from node.contract import SENSOR_CHANNELS
from node.training.runs import read_runs
from simulator.gaspath import NB_TOP

log = logging.getLogger(__name__)

RESONANCE_BANDS = ((0.80, 0.85), (0.94, 0.965))  # dissertation, sections 3.3 and 5.2


def _runs(args: argparse.Namespace) -> list[tuple[str, np.ndarray, np.ndarray, float | None]]:
    """(label, nB, yB, shutdown_before s) per run."""
    if args.recording:
        out = []
        for r in read_runs(args.recording, channels=["nB", "yB"]):
            out.append(("", r.column("nB"), r.column("yB"), r.shutdown_before))
        return out
    from simulator.campaign import simulate_campaign

    camp = simulate_campaign(args.runs, args.seed)
    nb, yb = SENSOR_CHANNELS.index("nB"), SENSOR_CHANNELS.index("yB")
    return [("", r.data[:, nb], r.data[:, yb], r.truth["shutdown_before_s"]) for r in camp.runs]


def _smooth(x: np.ndarray, n: int = 41) -> np.ndarray:
    """Centred moving average ignoring NaN (n samples)."""
    ok = ~np.isnan(x)
    k = np.ones(n)
    num = np.convolve(np.where(ok, x, 0.0), k, mode="same")
    den = np.convolve(ok.astype(float), k, mode="same")
    return np.where(den > 0, num / np.maximum(den, 1), np.nan)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recording", default=None)
    p.add_argument("--runs", type=int, default=6)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default="docs/characteristic_curve.png")
    args = p.parse_args(argv)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.error("characteristic_plot: matplotlib is not installed")
        return 2

    runs = _runs(args)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [3, 2]})
    colors = plt.cm.viridis(np.linspace(0.0, 0.9, len(runs)))
    for i, ((_, nb, yb, shut), c) in enumerate(zip(runs, colors, strict=True)):
        x = nb / NB_TOP
        hist = "cold start" if shut is None else f"after {shut / 3600:.1f} h off"
        ax.plot(x, yb, ".", ms=0.6, color=c, alpha=0.25, rasterized=True)
        ax.plot(x, _smooth(yb), "-", lw=0.9, color=c, label=f"run {i + 1} ({hist})")
        bx.plot(x, _smooth(yb), "-", lw=1.0, color=c)
    for a in (ax, bx):
        for lo, hi in RESONANCE_BANDS:
            a.axvspan(lo, hi, color="tab:red", alpha=0.08, lw=0)
        a.set_xlabel("nB / top speed (9800 rpm)")
        a.grid(alpha=0.3)
    ax.set_xlim(0.25, 1.01)
    ax.set_ylabel("yB, tracked order-1 amplitude (mm/s peak)")
    ax.set_title("Characteristic curve of simulated pass-off runs (one engine)")
    ax.legend(loc="upper left", fontsize=8, markerscale=8)
    ax.text(0.825, ax.get_ylim()[1] * 0.97, "0.80-0.85", ha="center", va="top", fontsize=8)
    ax.text(0.9525, ax.get_ylim()[1] * 0.97, "0.94-0.965", ha="center", va="top", fontsize=8)
    bx.set_xlim(0.74, 1.005)
    bx.set_title("Zoom on the resonances (smoothed): run-to-run dispersion")
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
