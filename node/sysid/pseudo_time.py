"""A parametric ROM of a tracked order's amplitude through a pseudo-time signal (dissertation
section 6.4.2).

Models of order amplitudes mix their poles up from run to run; the text instead rebuilds a
time-domain signal from the amplitudes by order analysis, x(t) = a(t) cos phi(t), the 1st order
of a shaft turning at the measured speed, upsampled (the upsampling factor a hyper-parameter), and
fits a single-input model (speed in, x out; Delay-DMD) per run, whose poles sit at the carrier
and are trackable across runs. The library (one model per run at its parameter value) is
interpolated in pole-residue form (:class:`~node.sysid.parametric.ParametricROM`); the model at
a new run's parameter is run over the speed and demodulated back to the amplitude.

The carrier here is a pseudo shaft: its frequency follows the speed, ``cycles`` samples of the
upsampled signal per turn at the training runs' mean speed (the engine's own shaft frequency
would need an upsampling factor set by the highest speed; the text's axes are normalised and
its carrier is not given). Demodulation: x e^{-i phi} averaged over the turn about each sample (the 2 phi
term cancels; the integral in phi, so at any speed), twice its modulus, every ``up``-th sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from node.sysid.delay_dmd import DelayDMD
from node.sysid.memo import ContentMemo
from node.sysid.observer import estimate_state
from node.sysid.parametric import ParametricROM
from node.sysid.statespace import StateSpace

DRIVES = ("speed", "force")
# a library sample's Delay-DMD, by its signals and delays: leave-one-run-out CV refits the same runs
_MODELS: ContentMemo[StateSpace] = ContentMemo(256)


def upsample(a: np.ndarray, up: int) -> np.ndarray:
    """(K * up,) linear interpolation of a (K,) onto ``up`` points per sample (the last held)."""
    K = len(a)
    t = np.arange(K * up) / up
    return np.interp(t, np.arange(K), a)


def phase(speed: np.ndarray, up: int, ref: float, cycles: int, phi0: float = 0.0) -> np.ndarray:
    """(K * up,) the pseudo shaft's angle (rad): ``cycles`` samples per turn at speed ``ref``,
    from ``phi0`` at the first upsampled sample; speed (K,) (any unit, as ``ref``)."""
    rate = 2 * np.pi / cycles * upsample(np.maximum(speed, 0.0), up) / ref  # rad per upsampled sample
    return phi0 + np.concatenate([[0.0], np.cumsum(rate[:-1])])


def modulate(amplitude: np.ndarray, angle: np.ndarray, up: int) -> np.ndarray:
    """(K * up,) the pseudo-time signal a(t) cos phi(t) of amplitudes (K,) at angles (K * up,)."""
    return upsample(amplitude, up) * np.cos(angle)


def demodulate(x: np.ndarray, angle: np.ndarray, up: int) -> np.ndarray:
    """(len(x) // up,) amplitudes of the pseudo-time signal x at the carrier's angles ``angle``
    (increasing, rad): twice the modulus of the mean of x e^{-i phi} over the turn centred on
    each sample (the trapezoidal integral in phi: the carrier's 2 phi term cancels at any
    speed; at the ends, the part of the turn there is), at every ``up``-th sample."""
    z = x * np.exp(-1j * angle)
    c = np.concatenate([[0.0], np.cumsum(0.5 * (z[1:] + z[:-1]) * np.diff(angle))])
    lo = np.clip(angle - np.pi, angle[0], angle[-1])
    hi = np.clip(angle + np.pi, angle[0], angle[-1])

    def at(a: np.ndarray) -> np.ndarray:
        return np.interp(a, angle, c.real) + 1j * np.interp(a, angle, c.imag)

    span = hi - lo
    mean = np.where(span > 0, (at(hi) - at(lo)) / np.where(span > 0, span, 1.0), z)
    return np.asarray(2.0 * np.abs(mean[::up]))


@dataclass(frozen=True)
class Run:
    """One run's OC segment with its past: amplitude (K,), speed (K,), the OC's first sample
    ``start`` (the samples before are measured past) and the parameter value(s) ``p`` (q,)."""

    amplitude: np.ndarray
    speed: np.ndarray
    start: int
    p: np.ndarray


class PseudoTimePROM:
    """Section 6.4.2's parametric model of an order amplitude (module docstring).

    Args:
        up: upsampling factor (pseudo-time samples per amplitude sample).
        delays: Delay-DMD's delays (tau).
        cycles: pseudo-time samples per turn of the carrier at the training runs' mean speed.
        n_pairs, n_real: the pole pairs and real poles the ROM keeps.
        weights: the ROM's weights (``"linear"``, ``"regress"``, ...).
        seed: pseudo-time samples of measured past the state is fitted on.
        drive: the model's input: ``"speed"`` (the text's: the speed / its training mean), or
            ``"force"``, the imbalance force of the pseudo shaft, (speed / mean)^2 cos phi: a
            linear model driven by the speed alone has nothing at the carrier to sustain the
            signal, and its free run decays over a long segment; driven by the force, the order
            is the structure's response to it, resonances and all.

    Learned: ``rom_`` (the :class:`ParametricROM`, built from the runs' models), ``models_``
    (their Delay-DMD models), ``ref_`` (the mean training speed).

    A tone whose amplitude settles to a level set by p, at a constant speed:

    >>> def run(p, K=200):
    ...     a = 1.0 + p * (1 - np.exp(-np.arange(K) / 20.0))
    ...     return Run(a, np.full(K, 5000.0), 40, np.array([p]))
    >>> m = PseudoTimePROM(up=4, delays=4, n_pairs=1, n_real=0).fit([run(p) for p in (0.0, 0.5, 1.0)])
    >>> bool(np.max(np.abs(m.predict(run(0.25)) - run(0.25).amplitude[40:])) < 0.15)
    True
    """

    def __init__(self, up: int = 8, delays: int = 8, cycles: int = 8, n_pairs: int = 3, n_real: int = 1,
                 weights: str = "linear", seed: int = 80, drive: str = "speed") -> None:
        self.up = up
        self.delays = delays
        self.cycles = cycles
        self.n_pairs = n_pairs
        self.n_real = n_real
        self.weights = weights
        self.seed = seed
        self.drive = drive

    def signals(self, run: Run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The run's pseudo-time signal x (K up, 1), input (K up, 1) (``drive``) and carrier angle."""
        angle = phase(run.speed, self.up, self.ref_, self.cycles)
        x = modulate(run.amplitude, angle, self.up)
        u = upsample(run.speed / self.ref_, self.up)
        return x[:, None], (u if self.drive == "speed" else u ** 2 * np.cos(angle))[:, None], angle

    def fit(self, library: Sequence[Run | Sequence[Run]]) -> PseudoTimePROM:
        """A Delay-DMD per library sample (a run, or several segments of one run: the first's
        parameter) on its pseudo-time signal (the past warms the delays), the ROM over the samples'
        parameters (the fitted models as its library; no validation: a free run from rest is not
        how the model is used). Returns self."""
        if self.drive not in DRIVES:
            raise ValueError(f"drive must be one of {DRIVES}, got {self.drive!r}")
        groups = [[entry] if isinstance(entry, Run) else list(entry) for entry in library]
        if len(groups) < 2 or any(not g for g in groups):
            raise ValueError(f"need at least 2 library samples of one or more runs, got {len(groups)}")
        self.ref_ = float(np.mean(np.concatenate([r.speed[r.start:] for g in groups for r in g])))
        if not np.isfinite(self.ref_) or self.ref_ <= 0:
            raise ValueError("the training runs' mean speed must be positive and finite")
        self.models_: list[StateSpace] = []
        for g in groups:
            pairs = [self.signals(r)[:2] for r in g]
            xs, us = [x for x, _ in pairs], [u for _, u in pairs]
            self.models_.append(_MODELS.get([np.array([self.delays, self.up]), *xs, *us],
                                            partial(self._delay_dmd, xs, us)))
        P = np.array([np.atleast_1d(g[0].p) for g in groups], float)
        self.rom_ = ParametricROM(None, n_pairs=self.n_pairs, n_real=self.n_real, weights=self.weights,
                                  match="assignment", block="none", tol=10.0, static=True, clip=True,
                                  verbose=False, fallback="drop").fit_models(self.models_, P)
        return self

    def _delay_dmd(self, xs: list[np.ndarray], us: list[np.ndarray]) -> StateSpace:
        """The Delay-DMD (least squares, the first ``delays`` samples warm-up) of one library sample."""
        est = DelayDMD(delays=self.delays, dt=1.0 / self.up, estimator="ls", warmup=self.delays,
                       seed_window=0)
        return est.fit(xs if len(xs) > 1 else xs[0], us if len(us) > 1 else us[0]).model_

    def predict(self, run: Run) -> np.ndarray:
        """(K - start,) the amplitude over the run's OC segment: the ROM at the run's parameter,
        its state fitted on the last ``seed`` pseudo-time samples of the past, run over the speed,
        demodulated."""
        x, u, angle = self.signals(run)
        m = self.rom_.at(np.clip(np.atleast_1d(run.p), self.rom_.params_.min(axis=0),
                                 self.rom_.params_.max(axis=0))).model_
        k0 = run.start * self.up
        W = min(self.seed, k0)
        x0 = estimate_state(m, x[k0 - W:k0], u[k0 - W:k0], None, rcond=1e-4) if W else np.zeros(m.n_states)
        xh = np.r_[x[:k0, 0], m.simulate(u[k0:], x0)[:, 0]]
        return demodulate(xh, angle, self.up)[run.start:]
