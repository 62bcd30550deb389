"""Two-degree-of-freedom systems whose modes cross, nearly cross or veer.

Unit masses, springs k1 (p) = w0^2 (1 + p) + k_c and k2 = w0^2 + k_c to ground, a coupling
spring k_c = ``coupling`` w0^2 between them (w0 = 2 pi 3 Hz): at p = 0 the uncoupled
frequencies coincide. Uncoupled (0), the first mode crosses the second with fixed shapes;
weakly coupled (0.03), they nearly cross (a 3 % gap, the shapes swap within +-0.1 of p);
strongly coupled (0.2), they veer (3.0 and 3.55 Hz at p = 0, the shapes turning over the whole
range). Rayleigh damping, 2 % of critical at 3 Hz; a force on both masses (1 and 0.5 N per
unit input), both displacements out (cm); exact ZOH at 100 Hz.

:func:`score` fits a :class:`node.sysid.WDMD` per parameter sample as
:class:`node.sysid.ParametricROM` does, and scores on a chirp none of the fits saw the
interpolated model, the model fitted at the new parameter itself and the nearest sample's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from harness.beam import chirp, quadratic_chirp
from node.sysid import WDMD, ParametricROM, StateSpace, eps_td

FS = 100.0  # Hz
F0 = 3.0  # Hz, both uncoupled modes at p = 0
ZETA = 0.02
CASES = {"crossing": 0.0, "near-crossing": 0.03, "veering": 0.2}  # coupling k_c / w0^2
LIBRARY = (-0.4, -0.2, 0.2, 0.4)
TARGET = 0.0


def system(p: float, coupling: float) -> StateSpace:
    """The discrete 2-DOF model at parameter ``p`` (1 input, 2 outputs, 4 states)."""
    w2 = (2 * np.pi * F0) ** 2
    kc = coupling * w2
    K = np.array([[w2 * (1 + p) + kc, -kc], [-kc, w2 + kc]])
    w0 = 2 * np.pi * F0
    D = ZETA * w0 * np.eye(2) + ZETA / w0 * K
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -D]])
    B = np.r_[np.zeros((2, 1)), np.array([[1.0], [0.5]])]
    E = linalg.expm(np.block([[A, B], [np.zeros((1, 5))]]) / FS)
    C = np.hstack([np.eye(2), np.zeros((2, 2))]) * 100.0
    return StateSpace(E[:4, :4], E[:4, 4:], C, np.zeros((2, 1)), 1.0 / FS)


def frequencies(ss: StateSpace) -> np.ndarray:
    """Damped natural frequencies (Hz) of the upper-half-plane poles, ascending."""
    z = ss.poles()
    return np.sort(np.angle(z[z.imag > 0]) * FS / (2 * np.pi))


def train_input() -> np.ndarray:
    """The fits' input (3000, 1): a quadratic chirp 0.2-12 Hz over 30 s."""
    return quadratic_chirp(FS, 30.0, 0.2, 12.0)[:, None]


def test_input() -> np.ndarray:
    """The scoring input (2000, 1): a linear chirp 0.5-10 Hz over 20 s, amplitude 1.3."""
    return 1.3 * chirp(FS, 20.0, 0.5, 10.0)[:, None]


def base() -> WDMD:
    return WDMD(levels=5, rcond=1e-8, dt=1.0 / FS)


@dataclass(frozen=True)
class Score:
    """eps_td at the target on the unseen chirp: the ROM, the model fitted there, the nearest
    sample's model; and the ROM itself."""

    rom: float
    own: float
    nearest: float
    model: ParametricROM


def score(coupling: float, noise: float = 0.0, library: tuple[float, ...] = LIBRARY,
          target: float = TARGET, **rom_params: object) -> Score:
    """Fit at ``library`` (outputs with white noise of ``noise`` x their std, one seed per
    sample), interpolate to ``target`` and score there against the noise-free truth."""
    u, v = train_input(), test_input()

    def measure(p: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
        y = system(p, coupling).simulate(u)
        rng = np.random.default_rng(seed)
        return y + noise * y.std(axis=0) * rng.standard_normal(y.shape), u

    samples = [measure(p, i) for i, p in enumerate(library)]
    truth = system(target, coupling).simulate(v)
    own = base().fit(*measure(target, len(library))).model_
    near = int(np.argmin(np.abs(np.asarray(library) - target)))
    rom = ParametricROM(base(), n_pairs=2, **rom_params).fit(samples, list(library))  # type: ignore[arg-type]
    with np.errstate(all="ignore"):
        return Score(eps_td(truth, rom.at(target).simulate(v)), eps_td(truth, own.simulate(v)),
                     eps_td(truth, rom.estimators_[near].model_.simulate(v)), rom)
