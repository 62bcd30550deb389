"""A generated family of parametric systems for :class:`node.sysid.ParametricROM`: 2-4 DOF
spring-mass chains whose modes cross, veer or neither as one stiffness or one mass follows the
parameter p in [0, 1].

Each case (:func:`make_case`, seeded): n unit-scale masses in a chain, each on a spring to
ground (uncoupled frequencies 1.5-7 Hz, at least 25 % apart), neighbours joined by coupling
springs; DOF j's grounded stiffness (or its mass) moves with p:

* ``crossing``: j has no coupling spring, and its frequency passes another DOF's at p* in
  (0.3, 0.7): the modes cross with fixed shapes;
* ``veering``: j is coupled to a neighbour k (coupling 0.03-0.2 of k's stiffness) whose
  uncoupled frequency j's passes at p*: the modes veer, their shapes turn into each other;
* ``neither``: j's frequency moves 10-40 % and stays at least 25 % from every other's.

Rayleigh damping 1-3 % at 3 Hz; a force on every mass (random weights 0.3-1 N per unit input);
every displacement out (cm); exact ZOH at 100 Hz. Output noise 0, 1 or 2 % of each output's std.
Trained at 3-5 unevenly spaced samples in [0, 1] (a quadratic chirp 0.2-12 Hz over 30 s, as
:mod:`harness.veering`), judged at an interior point (the crossing or veering point, else a
random one) on a linear chirp none of the fits saw, against the noise-free truth: the default
``ParametricROM(WDMD)``, a WDMD fitted directly at that point (its own noisy data) and the
nearest sample's WDMD.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import linalg

from harness.veering import base, test_input, train_input
from node.sysid import ParametricROM, StateSpace, eps_td
from node.sysid.parametric import ParametricFallbackWarning

FS = 100.0  # Hz
KINDS = ("crossing", "veering", "neither")
NOISES = (0.0, 0.01, 0.02)
# the targets (issue text): no worse than the nearest sample's model in >= 97 % of cases; within
# 2x a direct fit or 0.05 eps_td of it in >= 90 %; every fallback warned
TARGET_NEAREST, TARGET_DIRECT = 0.97, 0.90
TUNED = range(0, 40)  # the seeds the validation's rules were chosen on; the others are held out


@dataclass(frozen=True)
class Case:
    """One generated system: ``kind``, ``noise``, the chain (``ground`` (n,) rad^2/s^2 per unit
    mass, ``couple`` (n - 1,), ``mass`` (n,)), the moving DOF ``j``, whether its ``stiffness``
    (else its mass) moves and by ``rate`` (relative per unit p), ``force`` (n,), ``zeta``, the
    training ``samples`` and the ``target`` p."""

    seed: int
    kind: str
    noise: float
    ground: np.ndarray
    couple: np.ndarray
    mass: np.ndarray
    j: int
    stiffness: bool
    rate: float
    force: np.ndarray
    zeta: float
    samples: tuple[float, ...]
    target: float

    @property
    def n(self) -> int:
        return len(self.ground)

    def label(self) -> str:
        what = "k" if self.stiffness else "m"
        return (f"#{self.seed} {self.kind} {self.n}-DOF {what}{self.j}(p) noise {self.noise:.0%} "
                f"samples {','.join(f'{p:.2f}' for p in self.samples)} -> {self.target:.2f}")


def system(case: Case, p: float) -> StateSpace:
    """The discrete model at p: (1 input, n outputs, 2n states)."""
    n = case.n
    g = case.ground.copy()
    m = case.mass.copy()
    if case.stiffness:
        g[case.j] *= 1.0 + case.rate * p
    else:
        m[case.j] *= 1.0 + case.rate * p
    K = np.diag(g)
    for i, c in enumerate(case.couple):
        K[i:i + 2, i:i + 2] += c * np.array([[1.0, -1.0], [-1.0, 1.0]])
    M = np.diag(m)
    w0 = 2 * np.pi * 3.0
    Cd = case.zeta * w0 * M + case.zeta / w0 * K
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ Cd]])
    B = np.r_[np.zeros((n, 1)), Mi @ case.force[:, None]]
    E = linalg.expm(np.block([[A, B], [np.zeros((1, 2 * n + 1))]]) / FS)
    C = np.hstack([np.eye(n), np.zeros((n, n))]) * 100.0
    return StateSpace(E[:2 * n, :2 * n], E[:2 * n, 2 * n:], C, np.zeros((n, 1)), 1.0 / FS)


def _spread(rng: np.random.Generator, n: int) -> np.ndarray:
    """n uncoupled frequencies (Hz) in 1.5-7, ascending, each at least 25 % above the one below."""
    while True:
        f = np.sort(rng.uniform(1.5, 7.0, n))
        if np.all(f[1:] / f[:-1] > 1.25):
            return f


def _samples(rng: np.random.Generator, count: int) -> tuple[float, ...]:
    """``count`` unevenly spaced samples in [0, 1], the ends included, at least 0.12 apart."""
    while True:
        inner = np.sort(rng.uniform(0.1, 0.9, count - 2))
        p = np.r_[0.0, inner, 1.0]
        gaps = np.diff(p)
        if gaps.min() >= 0.12 and (count < 4 or gaps.max() / gaps.min() > 1.3):
            return tuple(float(x) for x in p)


def make_case(seed: int, kind: str | None = None, noise: float | None = None) -> Case:
    """The case of ``seed`` (kind and noise cycle with the seed unless given)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[seed % 3] if kind is None else kind
    noise = NOISES[(seed // 3) % 3] if noise is None else noise
    n = int(rng.integers(2, 5))
    f = _spread(rng, n)
    w2 = (2 * np.pi * f) ** 2
    stiffness = bool(rng.integers(0, 2))
    couple = w2[:-1] * rng.uniform(0.05, 0.2, n - 1)
    samples = _samples(rng, int(rng.integers(3, 6)))
    if kind == "neither":
        j = int(rng.integers(0, n))
        others = np.delete(f, j)
        move = 0.05
        for _ in range(100):
            trial = rng.uniform(0.1, 0.4) * rng.choice([-1.0, 1.0])  # relative frequency change
            fj = f[j] * (1 + trial * np.linspace(0, 1, 11))
            if others.size == 0 or np.min(np.abs(fj[:, None] / others[None, :] - 1)) > 0.25:
                move = trial
                break
        ratio = (1 + move) ** 2  # of j's uncoupled w^2 at p = 1
        rate = ratio - 1 if stiffness else 1 / ratio - 1
        lo, hi = samples[0] + 0.5 * (samples[1] - samples[0]), samples[-1] - 0.5 * (samples[-1] - samples[-2])
        target = float(rng.uniform(lo, hi))
    else:
        # a stiffer j rises to the DOF above it, a heavier one falls to the DOF below: the
        # uncoupled frequencies meet at p = target
        j = int(rng.integers(0, n - 1)) if stiffness else int(rng.integers(1, n))
        k = j + 1 if stiffness else j - 1
        target = float(rng.uniform(0.3, 0.7))
        rate = float((w2[k] / w2[j] - 1) / target if stiffness else (w2[j] / w2[k] - 1) / target)
        if kind == "crossing":
            couple[max(j - 1, 0):j + 1] = 0.0  # j's springs to its neighbours
        else:
            couple[min(j, k)] = w2[k] * rng.uniform(0.03, 0.2)
    target = float(np.clip(target, samples[0] + 0.03, samples[-1] - 0.03))
    ground = w2.copy()
    return Case(seed, kind, float(noise), ground, couple, np.ones(n), j, stiffness, float(rate),
                rng.uniform(0.3, 1.0, n) * rng.choice([-1.0, 1.0], n), float(rng.uniform(0.01, 0.03)),
                samples, target)


@dataclass(frozen=True)
class Result:
    """eps_td at the target of the default ROM, the direct fit and the nearest sample's model; whether
    the ROM fell back (whole or some modes) and whether it warned."""

    case: Case
    rom: float
    direct: float
    nearest: float
    fell_back: bool
    warned: bool
    summary: str

    @property
    def not_worse(self) -> bool:
        return self.rom <= self.nearest * (1 + 1e-9)

    @property
    def near_direct(self) -> bool:
        return self.rom <= 2 * self.direct or self.rom - self.direct <= 0.05

    @property
    def honest(self) -> bool:
        return self.warned or not self.fell_back


def run_case(case: Case, **rom_params: object) -> Result:
    """Fit and judge one case (the default ROM unless ``rom_params`` say otherwise)."""
    u, v = train_input(), test_input()

    def measure(p: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
        y = system(case, p).simulate(u)
        rng = np.random.default_rng([case.seed, seed])
        return y + case.noise * y.std(axis=0) * rng.standard_normal(y.shape), u

    data = [measure(p, i) for i, p in enumerate(case.samples)]
    truth = system(case, case.target).simulate(v)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ParametricFallbackWarning)
        rom = ParametricROM(base(), **rom_params).fit(data, list(case.samples))  # type: ignore[arg-type]
    warned = any(issubclass(w.category, ParametricFallbackWarning) for w in caught)
    direct = base().fit(*measure(case.target, len(case.samples))).model_
    near = int(np.argmin(np.abs(np.asarray(case.samples) - case.target)))
    with np.errstate(all="ignore"):
        scores = [eps_td(truth, m.simulate(v)) for m in (rom.at(case.target).model_, direct,
                                                         rom.estimators_[near].model_)]
    scores = [s if np.isfinite(s) else float("inf") for s in scores]
    fell = bool(rom.fallback_ or rom.to_arrays()["rom_fb_s_re"].shape[1])
    return Result(case, scores[0], scores[1], scores[2], fell, warned, rom.validation_.summary())


def run(seeds: range | list[int], **rom_params: object) -> list[Result]:
    """:func:`run_case` of :func:`make_case` for each seed."""
    return [run_case(make_case(s), **rom_params) for s in seeds]


def fractions(results: list[Result]) -> dict[str, float]:
    """Pass fractions of the three rules over ``results``."""
    n = max(len(results), 1)
    return {"not worse than nearest": sum(r.not_worse for r in results) / n,
            "within 2x or 0.05 of direct": sum(r.near_direct for r in results) / n,
            "fallbacks warned": sum(r.honest for r in results) / n}
