"""Imbalanced-rotor beam benchmark (dissertation section 5.4, Table 5.1).

    python -m bench rotor [--quick] [--extra-levels 3 5] [--workers 2]

The finite-element cantilever of :mod:`harness.beam` (30 nodes) carries an
imbalanced rotor at node 13. The rotor pushes the beam transversely with

    F(t) = m e w(t)^2 sin(theta(t)),  w = 2 pi rpm / 60 (rad/s),  theta = integral of w dt,

and the transverse displacements at nodes 28, 29, 30 are measured. One run of
the RPM profile (Fig. 5.3/5.4) is simulated; it holds two operating conditions,
OC1 (1150-1560 rpm) and OC2 (1561-3200 rpm, through the first bending mode at
~2630 rpm), each a training phase followed by three testing phases: (i) a
steady plateau, (ii) a ramp unlike the training ramps, (iii) a non-stationary
up-down sweep.

Per OC a WDMD model (J = 4, Haar: 3 x 5 = 15 pseudo-states) is trained on the
raw displacements, its input being the imbalance force: a linear model of the
raw response needs the force (the rpm enters through w^2 and the phase
sin(theta), not linearly). The order-1 amplitude is then tracked (Vold-Kalman
filter) in the model's free-run response and in the noise-free true response,
and eps_td (eq. 5.20, over the three outputs) compares the two. Training:
the training input replayed (from rest for OC1, seeded from the measured
history before it for OC2). Testing: the three phases simulated one after
another, each seeded from the measured history before it, tracked as one span.

Noise: white, a fraction of each output's std over the OC's training phase,
added to every measured output (training data and seeding histories); errors
are always against the noise-free truth. Mean over 5 realizations (the text
used 50); a realization whose model is unstable is counted, not averaged.
A second table shows the OC2 model's poles per noise level: least squares on
noisy MODWT pseudo-states (errors in variables, correlated between k and k+1)
biases A, and the OE step re-estimates only B and D.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import time
from dataclasses import dataclass

import numpy as np

from harness import beam as bm
from node.cli.table import print_table
from node.order_tracking import shaft_revolutions, vkf_orders
from node.sysid import WDMD, eps_td

FS = 1000.0                 # Hz, sample rate of the run
ROTOR_NODE = 13
OUTPUT_NODES = [28, 29, 30]
MASS_ECC = 1e-4             # kg m, imbalance m * e (e.g. 20 g at 5 mm)
LEVELS = 4                  # J, as the text
VKF_BANDWIDTH_HZ = 2.0      # full -3 dB bandwidth of the order tracker
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

# RPM profile: per OC, phases of (rpm knot, seconds to reach it from the previous knot).
# A knot with the same rpm as the previous one is a plateau. Each phase continues
# from the last rpm of the phase before.
PROFILE: dict[str, dict] = {
    "OC1": {
        "range": (1150.0, 1560.0),
        "start": 1200.0,
        "phases": {
            "train": [(1200, 1.5), (1500, 3), (1500, 2), (1250, 2.5), (1250, 1.5), (1420, 1.5),
                      (1420, 1.5)],
            "test i": [(1420, 3)],
            "test ii": [(1180, 2.5), (1180, 0.5)],
            "test iii": [(1450, 1), (1300, 1), (1550, 1.5), (1200, 1.5), (1560, 1.5)],
        },
    },
    "OC2": {
        "range": (1561.0, 3200.0),
        "start": 1561.0,
        "phases": {
            "train": [(2000, 2.5), (2000, 1.5), (2900, 4), (2900, 2), (2200, 3), (2200, 1.5),
                      (3150, 3.5), (3150, 1.5), (2500, 2.5)],
            "test i": [(2500, 3)],
            "test ii": [(3100, 3.5), (3100, 0.5)],
            "test iii": [(1800, 2.5), (3000, 2.5), (2200, 2), (2800, 2)],
        },
    },
}
TEST_PHASES = ["test i", "test ii", "test iii"]


# --- the run --------------------------------------------------------------------
def rpm_segment(start: float, knots: list[tuple[float, float]], fs: float) -> np.ndarray:
    """Piecewise-linear speed (K,) in rev/min through ``knots`` (rpm, seconds) from ``start``."""
    parts = []
    prev = start
    for rpm, dur in knots:
        n = int(round(dur * fs))
        parts.append(prev + (rpm - prev) * (np.arange(1, n + 1) / n))
        prev = rpm
    return np.concatenate(parts)


@dataclass
class Run:
    """The simulated run (time-major) and where each OC's phases lie in it.

    rpm (K,) rev/min, force (K, 1) N, y (K, 3) m noise-free displacements,
    spans {(oc, phase): (start, stop)} sample indices.
    """

    fs: float
    rpm: np.ndarray
    force: np.ndarray
    y: np.ndarray
    spans: dict[tuple[str, str], tuple[int, int]]


def rpm_profile(fs: float = FS) -> tuple[np.ndarray, dict[tuple[str, str], tuple[int, int]]]:
    """The whole speed profile (K,) rev/min and the sample span of every (OC, phase)."""
    pieces, spans, k = [], {}, 0
    for oc, cfg in PROFILE.items():
        prev = cfg["start"]
        for phase, knots in cfg["phases"].items():
            seg = rpm_segment(prev, knots, fs)
            lo, hi = cfg["range"]
            if seg.min() < lo or seg.max() > hi:
                raise ValueError(f"{oc} {phase} leaves its range {lo}-{hi} rpm")
            spans[(oc, phase)] = (k, k + len(seg))
            pieces.append(seg)
            k += len(seg)
            prev = seg[-1]
    return np.concatenate(pieces), spans


def imbalance_force(rpm: np.ndarray, fs: float, mass_ecc: float = MASS_ECC) -> np.ndarray:
    """F = m e w^2 sin(theta) (K,) in N; theta integrated from rpm (rev/min) as the tracker does."""
    w = 2 * np.pi * rpm / 60.0
    theta = 2 * np.pi * shaft_revolutions(rpm, fs)
    return mass_ecc * w ** 2 * np.sin(theta)


def beam_spec(fs: float = FS) -> bm.BeamSpec:
    """Our FE beam (section 4.4 dimensions) sampled at ``fs``."""
    return dataclasses.replace(bm.BeamSpec(), fs=fs)


def simulate_run(fs: float = FS) -> Run:
    """Simulate the beam (from rest) over the whole profile."""
    rpm, spans = rpm_profile(fs)
    force = imbalance_force(rpm, fs)[:, None]
    truth = bm.discrete_model(beam_spec(fs), [ROTOR_NODE], OUTPUT_NODES)
    return Run(fs, rpm, force, truth.simulate(force), spans)


def add_noise(run: Run, pct: float, rng: np.random.Generator) -> np.ndarray:
    """Measured outputs (K, 3): white noise of ``pct`` % of each output's std over the
    training phase of the OC a sample belongs to."""
    y = run.y.copy()
    if pct == 0:
        return y
    for oc in PROFILE:
        lo, hi = run.spans[(oc, "train")]
        sd = run.y[lo:hi].std(axis=0)
        start = lo
        stop = run.spans[(oc, TEST_PHASES[-1])][1]
        y[start:stop] += pct / 100 * sd * rng.standard_normal((stop - start, y.shape[1]))
    return y


# --- order tracking --------------------------------------------------------------
def order1_amplitudes(y: np.ndarray, rpm: np.ndarray, fs: float) -> np.ndarray:
    """Order-1 amplitude (K, p) of every output column of y (K, p) by the VKF."""
    return np.column_stack([
        vkf_orders(y[:, i], fs, rpm, [1.0], bandwidth_hz=VKF_BANDWIDTH_HZ).amplitudes[:, 0]
        for i in range(y.shape[1])])


# --- one OC ------------------------------------------------------------------------
def oc_predictions(run: Run, y_meas: np.ndarray, oc: str, model: WDMD) -> dict[str, np.ndarray]:
    """Fit ``model`` on the OC's measured training data; free-run responses (K_phase, 3).

    Returns {"train": replay of the training input, "test": the three testing
    phases simulated in sequence, each seeded from the measured history}.
    """
    lo, hi = run.spans[(oc, "train")]
    model.fit(y_meas[lo:hi], run.force[lo:hi])
    hist = None if lo == 0 else (y_meas[:lo], run.force[:lo])
    train = model.simulate(run.force[lo:hi], history=hist)
    tests = []
    for phase in TEST_PHASES:
        a, b = run.spans[(oc, phase)]
        tests.append(model.simulate(run.force[a:b], history=(y_meas[:a], run.force[:a])))
    return {"train": train, "test": np.vstack(tests)}


def oc_span(run: Run, oc: str, part: str) -> tuple[int, int]:
    """Sample span of the training phase or of the three testing phases together."""
    if part == "train":
        return run.spans[(oc, "train")]
    return run.spans[(oc, TEST_PHASES[0])][0], run.spans[(oc, TEST_PHASES[-1])][1]


@dataclass
class Truth:
    """Order-1 amplitudes of the noise-free response per (oc, part)."""

    amps: dict[tuple[str, str], np.ndarray]

    @classmethod
    def of(cls, run: Run) -> Truth:
        amps = {}
        for oc in PROFILE:
            for part in ("train", "test"):
                a, b = oc_span(run, oc, part)
                amps[(oc, part)] = order1_amplitudes(run.y[a:b], run.rpm[a:b], run.fs)
        return cls(amps)


def oc_errors(run: Run, truth: Truth, y_meas: np.ndarray, oc: str,
              model: WDMD) -> tuple[float, float]:
    """(train, test) eps_td of the order-1 amplitudes of the model's free run."""
    pred = oc_predictions(run, y_meas, oc, model)
    out = []
    for part in ("train", "test"):
        a, b = oc_span(run, oc, part)
        yp = pred[part]
        if not np.all(np.isfinite(yp)) or np.abs(yp).max() > 1e3 * np.abs(run.y).max():
            out.append(float("inf"))
            continue
        out.append(eps_td(truth.amps[(oc, part)], order1_amplitudes(yp, run.rpm[a:b], run.fs)))
    return out[0], out[1]


def make_model(estimator: str, levels: int = LEVELS, fs: float = FS) -> WDMD:
    """WDMD as the text (Haar, causal MODWT) with our rcond default and the given estimator."""
    return WDMD(levels=levels, wavelet="haar", rcond=1e-10, estimator=estimator, dt=1 / fs)


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench rotor", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 noise realizations instead of 3")
    ap.add_argument("--realizations", type=int, default=None, help="noise realizations per row")
    ap.add_argument("--workers", type=int, default=2, help="processes (1: no multiprocessing)")
    ap.add_argument("--extra-levels", type=int, nargs="*", default=[],
                    help="other J to show with the OE estimator (slower)")
    args = ap.parse_args(argv)
    n_real = args.realizations or (2 if args.quick else 3)
    t0 = time.perf_counter()
    run = simulate_run()
    truth = Truth.of(run)
    describe(run)
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
    print(f"\nTotal benchmark time: {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
