"""The imbalanced-rotor run of dissertation section 5.4 (Table 5.1) and its noise-free truth.

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
Measured outputs carry white noise scaled to each OC's training std (:func:`add_noise`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import cast

import numpy as np

from harness import beam as bm
from node.order_tracking import cot_orders, shaft_revolutions, tvdft_orders, vkf_orders
from node.sysid import WDMD, eps_td

FS = 1000.0                 # Hz, sample rate of the run
ROTOR_NODE = 13
OUTPUT_NODES = [28, 29, 30]
MASS_ECC = 1e-4             # kg m, imbalance m * e (e.g. 20 g at 5 mm)
LEVELS = 4                  # J, as the text
VKF_BANDWIDTH_HZ = 2.0      # full -3 dB bandwidth of the order tracker

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
    return Run(fs, rpm, force, cast(np.ndarray, truth.simulate(force)), spans)


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
TRACKERS = ("vkf", "tvdft", "cot")  # the order trackers the bench compares (section 3.2.1)
TVDFT_REVS = 8.0  # TVDFT window, revolutions (as COT's blocks)


def order1_amplitudes(y: np.ndarray, rpm: np.ndarray, fs: float, tracker: str = "vkf") -> np.ndarray:
    """Order-1 amplitude (K_out, p) of every output column of y (K, p): by the VKF (K_out = K),
    the TVDFT (K_out = K, NaN within half a window of either end) or COT (one row per block)."""
    def one(x: np.ndarray) -> np.ndarray:
        if tracker == "vkf":
            return vkf_orders(x, fs, rpm, [1.0], bandwidth_hz=VKF_BANDWIDTH_HZ).amplitudes[:, 0]
        if tracker == "tvdft":
            return tvdft_orders(x, fs, rpm, [1.0], block_revs=TVDFT_REVS).amplitudes[:, 0]
        if tracker == "cot":
            return cot_orders(x, fs, rpm, [1.0]).amplitudes[:, 0]
        raise ValueError(f"tracker must be one of {TRACKERS}, got {tracker!r}")
    return np.column_stack([one(y[:, i]) for i in range(y.shape[1])])


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
    def of(cls, run: Run, tracker: str = "vkf") -> Truth:
        amps = {}
        for oc in PROFILE:
            for part in ("train", "test"):
                a, b = oc_span(run, oc, part)
                amps[(oc, part)] = order1_amplitudes(run.y[a:b], run.rpm[a:b], run.fs, tracker)
        return cls(amps)


def oc_errors(run: Run, truth: Truth, y_meas: np.ndarray, oc: str,
              model: WDMD) -> tuple[float, float]:
    """(train, test) eps_td of the order-1 amplitudes (VKF) of the model's free run."""
    return prediction_errors(run, {"vkf": truth}, oc, oc_predictions(run, y_meas, oc, model))["vkf"]


def prediction_errors(run: Run, truths: dict[str, Truth], oc: str, pred: dict[str, np.ndarray]
                      ) -> dict[str, tuple[float, float]]:
    """Per tracker of ``truths``: (train, test) eps_td of the order-1 amplitudes of the OC's free
    runs ``pred`` (``oc_predictions``) against the truth's by the same tracker, on the rows where
    both are finite (the TVDFT's ends are not); inf for a model that blew up."""
    out: dict[str, tuple[float, float]] = {}
    for tracker, truth in truths.items():
        errs = []
        for part in ("train", "test"):
            a, b = oc_span(run, oc, part)
            yp = pred[part]
            if not np.all(np.isfinite(yp)) or np.abs(yp).max() > 1e3 * np.abs(run.y).max():
                errs.append(float("inf"))
                continue
            ref, got = truth.amps[(oc, part)], order1_amplitudes(yp, run.rpm[a:b], run.fs, tracker)
            ok = np.all(np.isfinite(ref), axis=1) & np.all(np.isfinite(got), axis=1)
            errs.append(eps_td(ref[ok], got[ok]))
        out[tracker] = (errs[0], errs[1])
    return out


def make_model(estimator: str, levels: int = LEVELS, fs: float = FS) -> WDMD:
    """WDMD as the text (Haar, causal MODWT) with our rcond default and the given estimator."""
    return WDMD(levels=levels, wavelet="haar", rcond=1e-10, estimator=estimator, dt=1 / fs)
