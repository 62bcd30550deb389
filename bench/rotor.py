"""Imbalanced-rotor beam benchmark (dissertation section 5.4, Table 5.1).

    python -m bench rotor [--quick] [--extra-levels 3 5] [--workers 2] [--trackers-only]

The run, its two operating conditions and the model are :mod:`harness.rotor`'s: the
finite-element cantilever of :mod:`harness.beam` (30 nodes) with an imbalanced rotor at
node 13, per OC a WDMD model (J = 4, Haar) trained on the raw displacements with the
imbalance force as input, and eps_td (eq. 5.20, over the three outputs) of the order-1
amplitudes (Vold-Kalman filter) of the model's free run against the noise-free truth's.

Noise: white, a fraction of each output's std over the OC's training phase,
added to every measured output (training data and seeding histories); errors
are always against the noise-free truth. Mean over 3 realizations (2 with --quick; the text
used 50); a realization whose model is unstable is counted, not averaged.
A second table shows the OC2 model's poles per noise level: least squares on
noisy MODWT pseudo-states (errors in variables, correlated between k and k+1)
biases A, and the OE step re-estimates only B and D.
A third table (alone with ``--trackers-only``) scores the same OE J = 4 models (one noise
realization at 0, 10 and 40 %) with the order-1 amplitudes extracted by each order tracker of
section 3.2.1: the Vold-Kalman filter (the table's), the time-variant DFT (``tvdft_orders``, 8
revolutions) and computed order tracking (``cot_orders``, 8-revolution blocks), each against the
noise-free truth by the same tracker, with the tracker's time to extract the truth.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time

import numpy as np

from harness import beam as bm
from harness.rotor import (
    LEVELS,
    MASS_ECC,
    OUTPUT_NODES,
    PROFILE,
    ROTOR_NODE,
    TRACKERS,
    VKF_BANDWIDTH_HZ,
    Run,
    Truth,
    add_noise,
    beam_spec,
    make_model,
    oc_errors,
    oc_predictions,
    prediction_errors,
    simulate_run,
)
from node.console.table import print_table

NOISE_PCT = [0, 5, 10, 15, 20, 40]

# Table 5.1 of the dissertation: noise % -> (OC1 train, OC1 test, OC2 train, OC2 test)
DISSERTATION = {
    0: (0.0006, 0.0046, 0.0406, 0.0283),
    5: (0.0438, 0.2831, 0.1887, 0.1645),
    10: (0.0783, 0.3351, 0.1294, 0.1023),
    15: (0.0975, 0.3104, 0.2186, 0.1338),
    20: (0.0861, 0.2955, 0.3076, 0.1948),
    40: (0.1703, 0.2926, 0.5702, 0.4203),
}

# --- the table -----------------------------------------------------------------------
Variant = tuple[str, int]  # (estimator, J)
_SHARED: dict[str, object] = {}  # run and truth, inherited by forked workers


def realization_errors(pct: float, seed: int,
                       variants: list[Variant]) -> dict[tuple[Variant, str], tuple[float, float]]:
    """(train, test) errors per (variant, oc) for one noise realization."""
    run, truth = _SHARED["run"], _SHARED["truth"]
    y_meas = add_noise(run, pct, np.random.default_rng(seed))
    out = {}
    with np.errstate(all="ignore"):
        for var in variants:
            for oc in PROFILE:
                out[(var, oc)] = oc_errors(run, truth, y_meas, oc,
                                           make_model(var[0], var[1], run.fs))
    return out


def noise_table(run: Run, truth: Truth, pcts: list[float], n_real: int, variants: list[Variant],
                workers: int = 2) -> dict[float, dict[tuple[Variant, str], list[tuple[float, float]]]]:
    """All (train, test) errors: {pct: {(variant, oc): [per realization]}}.

    The noise-free row has one realization; the others ``n_real``, the same noise
    for every variant (seed 1000 pct + r).
    """
    _SHARED.update(run=run, truth=truth)
    jobs = [(pct, 1000 * int(pct) + r) for pct in pcts for r in range(1 if pct == 0 else n_real)]
    if workers > 1:
        ctx = mp.get_context("fork")
        with ctx.Pool(workers) as pool:
            results = pool.starmap(realization_errors, [(p, s, variants) for p, s in jobs])
    else:
        results = [realization_errors(p, s, variants) for p, s in jobs]
    table: dict[float, dict] = {pct: {} for pct in pcts}
    for (pct, _), res in zip(jobs, results):
        for key, errs in res.items():
            table[pct].setdefault(key, []).append(errs)
    return table


def num(v: float) -> str:
    """4 decimals as Table 5.1, or 2 significant digits below 1e-3."""
    return f"{v:.4f}" if v >= 1e-3 else f"{v:.1e}"


def cell(errs: list[tuple[float, float]]) -> str:
    """'train / test' mean over the stable realizations, with the count of unstable ones."""
    arr = np.array(errs)
    ok = np.all(np.isfinite(arr), axis=1)
    if not ok.any():
        return "unstable"
    tr, te = arr[ok].mean(axis=0)
    text = f"{num(tr)} / {num(te)}"
    return text if ok.all() else f"{text} ({int((~ok).sum())}/{len(ok)} unstable)"


def pole_rows(run: Run, pcts: list[float], oc: str = "OC2") -> list[list[str]]:
    """Per noise level (first realization): the J = 4 model's A (LS and OE share it).

    Columns: spectral radius, largest real pole, and the pole nearest the first
    bending mode (Hz, damping ratio).
    """
    f1 = bm.natural_frequencies(beam_spec(run.fs))[0]
    lo, hi = run.spans[(oc, "train")]
    rows = []
    for pct in pcts:
        y_meas = add_noise(run, pct, np.random.default_rng(1000 * int(pct)))
        lam = make_model("ls", fs=run.fs).fit(y_meas[lo:hi], run.force[lo:hi]).model_.poles()
        real = lam[np.abs(lam.imag) < 1e-9]
        freqs = np.abs(np.angle(lam)) * run.fs / (2 * np.pi)
        i = int(np.argmin(np.abs(freqs - f1)))
        zeta = -np.log(np.abs(lam[i])) / np.abs(np.log(lam[i]))
        big_real = f"{real[np.argmax(np.abs(real))].real:.4f}" if real.size else "-"
        rows.append([str(pct), f"{np.max(np.abs(lam)):.4f}", big_real,
                     f"{freqs[i]:.2f} Hz, {zeta:.2%}"])
    return rows


TRACKER_PCTS = [0, 10, 40]


def tracker_rows(run: Run, pcts: list[float] = TRACKER_PCTS) -> list[list[str]]:
    """Per noise level (first realization) and OC: 'train / test' eps_td of the OE J = 4 model's
    order-1 amplitudes by each tracker (``TRACKERS``); the last row each tracker's time (s) to
    extract the truth's amplitudes."""
    truths, took = {}, {}
    for tracker in TRACKERS:
        t0 = time.perf_counter()
        truths[tracker] = Truth.of(run, tracker)
        took[tracker] = time.perf_counter() - t0
    rows = []
    for pct in pcts:
        y_meas = add_noise(run, pct, np.random.default_rng(1000 * int(pct)))
        for oc in PROFILE:
            with np.errstate(all="ignore"):
                pred = oc_predictions(run, y_meas, oc, make_model("oe", LEVELS, run.fs))
            errs = prediction_errors(run, truths, oc, pred)
            rows.append([str(pct), oc] + [cell([errs[t]]) for t in TRACKERS])
    rows.append(["time to track the truth", ""] + [f"{took[t]:.2f} s" for t in TRACKERS])
    return rows


def describe(run: Run) -> None:
    spec = beam_spec(run.fs)
    f_nat = bm.natural_frequencies(spec)
    print("# Imbalanced-rotor beam (dissertation section 5.4, Table 5.1)\n")
    print(f"Beam: FE cantilever of harness.beam, {spec.n_elements} elements (nodes 1-30 free), "
          f"damping {spec.zeta:.0%}; modes (Hz) " + ", ".join(f"{f:.1f}" for f in f_nat[:3])
          + f" (mode 1 = {60 * f_nat[0]:.0f} rpm); exact ZOH at {run.fs:.0f} Hz.")
    print(f"Rotor: imbalance m e = {MASS_ECC:g} kg m at node {ROTOR_NODE}, "
          f"F = m e w^2 sin(theta); outputs: displacements at nodes {OUTPUT_NODES}.")
    for oc, cfg in PROFILE.items():
        lo, hi = cfg["range"]
        parts = []
        for phase in cfg["phases"]:
            a, b = run.spans[(oc, phase)]
            seg = run.rpm[a:b]
            parts.append(f"{phase} {(b - a) / run.fs:.0f} s ({seg.min():.0f}-{seg.max():.0f} rpm)")
        print(f"{oc} ({lo:.0f}-{hi:.0f} rpm): " + ", ".join(parts))
    print(f"Model: WDMD J={LEVELS}, Haar, causal MODWT, rcond 1e-10, input = force (N), "
          f"{len(OUTPUT_NODES) * (LEVELS + 1)} pseudo-states. Order 1 by VKF "
          f"(bandwidth {VKF_BANDWIDTH_HZ:g} Hz) on model and noise-free responses.")


def _print_trackers(run: Run) -> None:
    print_table(["noise %", "OC", *(f"{t.upper()} train / test" for t in TRACKERS)], tracker_rows(run),
                markdown=True, title=f"eps_td of the OE J={LEVELS} model's order-1 amplitudes by order "
                "tracker (one realization; each against the noise-free truth by the same tracker)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench rotor", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 noise realizations instead of 3")
    ap.add_argument("--realizations", type=int, default=None, help="noise realizations per row")
    ap.add_argument("--workers", type=int, default=2, help="processes (1: no multiprocessing)")
    ap.add_argument("--extra-levels", type=int, nargs="*", default=[],
                    help="other J to show with the OE estimator (slower)")
    ap.add_argument("--trackers-only", action="store_true",
                    help="only the order trackers' table (VKF, TVDFT, COT)")
    args = ap.parse_args(argv)
    n_real = args.realizations or (2 if args.quick else 3)
    t0 = time.perf_counter()
    run = simulate_run()
    describe(run)
    if args.trackers_only:
        _print_trackers(run)
        print(f"\nTotal benchmark time: {time.perf_counter() - t0:.0f} s")
        return 0
    truth = Truth.of(run)
    variants: list[Variant] = [("ls", LEVELS), ("oe", LEVELS), ("pem", LEVELS)] + \
        [("oe", j) for j in args.extra_levels]
    table = noise_table(run, truth, NOISE_PCT, n_real, variants, args.workers)
    header, rows = ["noise %"], []
    for oc in PROFILE:
        header += [f"{oc} dissertation"] + [f"{oc} {e.upper()} J={j}" for e, j in variants]
    for pct in NOISE_PCT:
        d = DISSERTATION[pct]
        row = [str(pct)]
        for i, oc in enumerate(PROFILE):
            row.append(f"{d[2 * i]:.4f} / {d[2 * i + 1]:.4f}")
            row += [cell(table[pct][(var, oc)]) for var in variants]
        rows.append(row)
    print_table(header, rows, markdown=True,
                title=f"eps_td of the order-1 amplitudes, train / test (mean of {n_real} noise "
                "realizations; the dissertation used 50)")
    spec = beam_spec(run.fs)
    f1 = bm.natural_frequencies(spec)[0]
    z1 = np.exp(-spec.zeta * 2 * np.pi * f1 / run.fs)
    print_table(["noise %", "spectral radius", "largest real pole", "pole nearest mode 1"],
                pole_rows(run, NOISE_PCT), markdown=True,
                title=f"OC2 model, J={LEVELS}, one realization: poles of A of LS and OE (PEM moves them); "
                f"the FE beam's mode 1: {f1:.2f} Hz, {spec.zeta:.2%}, |z| = {z1:.4f}")
    _print_trackers(run)
    print(f"\nTotal benchmark time: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
