"""Finite-element Euler-Bernoulli cantilever beam of section 4.4 (the reference system).

The dissertation gives neither dimensions nor damping; ours (stated here and
printed by the benchmark):

* steel hollow square tube 40 x 40 x 3 mm, length 1.0 m, E = 210 GPa,
  rho = 7850 kg/m^3 (first bending modes near 44, 275, 770 Hz: three modes in
  the 10-800 Hz chirp band, the fourth just above it);
* 30 Hermite beam elements, the root (node 0) clamped, nodes 1..30 free, so
  60 DOF (transverse displacement and rotation per node) and 120 states;
* Rayleigh damping with 1 % of critical at the first and third modes;
* exact zero-order-hold discretisation at 5 kHz.

Outputs are nodal transverse displacements (m), inputs nodal forces (N).

Section 6.3 loads the beam axially: ``axial`` = P (N, compression) subtracts the
consistent geometric stiffness P N_g from K (eq. 6.4-6.5); the damping matrix is the
unloaded beam's, so it does not depend on P.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import linalg

from node.sysid import StateSpace


@dataclass(frozen=True)
class BeamSpec:
    length: float = 1.0          # m
    width: float = 0.040         # m, outer side of the square tube
    wall: float = 0.003          # m
    youngs: float = 210e9        # Pa
    density: float = 7850.0      # kg/m^3
    n_elements: int = 30
    zeta: float = 0.01           # damping ratio at modes 1 and 3
    fs: float = 5000.0           # Hz
    axial: float = 0.0           # N, axial compression P (section 6.3)

    @property
    def area(self) -> float:
        inner = self.width - 2 * self.wall
        return self.width ** 2 - inner ** 2

    @property
    def inertia(self) -> float:
        inner = self.width - 2 * self.wall
        return (self.width ** 4 - inner ** 4) / 12.0


def assemble(spec: BeamSpec) -> tuple[np.ndarray, np.ndarray]:
    """Mass and stiffness K - P N_g (60 x 60) of the clamped beam, DOF order [w1, th1, ..., w30, th30]."""
    ne, le = spec.n_elements, spec.length / spec.n_elements
    EI, rhoA = spec.youngs * spec.inertia, spec.density * spec.area
    ke = EI / le ** 3 * np.array([[12, 6 * le, -12, 6 * le],
                                  [6 * le, 4 * le ** 2, -6 * le, 2 * le ** 2],
                                  [-12, -6 * le, 12, -6 * le],
                                  [6 * le, 2 * le ** 2, -6 * le, 4 * le ** 2]])
    me = rhoA * le / 420 * np.array([[156, 22 * le, 54, -13 * le],
                                     [22 * le, 4 * le ** 2, 13 * le, -3 * le ** 2],
                                     [54, 13 * le, 156, -22 * le],
                                     [-13 * le, -3 * le ** 2, -22 * le, 4 * le ** 2]])
    ke = ke - spec.axial / (30 * le) * np.array([[36, 3 * le, -36, 3 * le],
                                                 [3 * le, 4 * le ** 2, -3 * le, -le ** 2],
                                                 [-36, -3 * le, 36, -3 * le],
                                                 [3 * le, -le ** 2, -3 * le, 4 * le ** 2]])
    ndof = 2 * (ne + 1)
    K = np.zeros((ndof, ndof))
    M = np.zeros((ndof, ndof))
    for e in range(ne):
        idx = slice(2 * e, 2 * e + 4)
        K[idx, idx] += ke
        M[idx, idx] += me
    return M[2:, 2:], K[2:, 2:]  # clamp node 0


def natural_frequencies(spec: BeamSpec) -> np.ndarray:
    """Undamped natural frequencies (Hz), ascending."""
    M, K = assemble(spec)
    w2 = linalg.eigh(K, M, eigvals_only=True)
    return np.sqrt(w2) / (2 * np.pi)


def mode_shapes(spec: BeamSpec, nodes: list[int], n_modes: int) -> np.ndarray:
    """Transverse mode shapes at ``nodes`` (1-based), (len(nodes), n_modes)."""
    M, K = assemble(spec)
    _, vecs = linalg.eigh(K, M)
    return vecs[[2 * (k - 1) for k in nodes]][:, :n_modes]


def continuous_model(spec: BeamSpec, input_nodes: list[int], output_nodes: list[int]):
    """(A, B, C) of eq. 4.37: 120 states [displacements, velocities]."""
    M, K = assemble(spec)
    w = 2 * np.pi * natural_frequencies(replace(spec, axial=0.0))  # damping of the unloaded beam
    a = 2 * spec.zeta * w[0] * w[2] / (w[0] + w[2])
    b = 2 * spec.zeta / (w[0] + w[2])
    G = a * M + b * K
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ G]])
    F = np.zeros((n, len(input_nodes)))
    for j, node in enumerate(input_nodes):
        F[2 * (node - 1), j] = 1.0
    B = np.vstack([np.zeros((n, len(input_nodes))), Minv @ F])
    C = np.zeros((len(output_nodes), 2 * n))
    for i, node in enumerate(output_nodes):
        C[i, 2 * (node - 1)] = 1.0
    return A, B, C


def discrete_model(spec: BeamSpec, input_nodes: list[int], output_nodes: list[int]) -> StateSpace:
    """Exact zero-order-hold discretisation at ``spec.fs``: the data-generating system."""
    Ac, Bc, C = continuous_model(spec, input_nodes, output_nodes)
    n, m = Bc.shape
    dt = 1.0 / spec.fs
    E = linalg.expm(np.block([[Ac, Bc], [np.zeros((m, n + m))]]) * dt)
    return StateSpace(E[:n, :n], E[:n, n:], C, np.zeros((C.shape[0], m)), dt)


def chirp(fs: float, duration: float, f0: float, f1: float, amplitude: float = 1.0) -> np.ndarray:
    """Linear chirp f0 -> f1 (Hz) over ``duration`` s, (K,)."""
    t = np.arange(int(round(duration * fs))) / fs
    return amplitude * np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t ** 2 / (2 * duration)))


def quadratic_chirp(fs: float, duration: float, f0: float, f1: float,
                    amplitude: float = 1.0) -> np.ndarray:
    """Chirp whose frequency rises quadratically f0 -> f1 (Hz) over ``duration`` s, (K,)."""
    t = np.arange(int(round(duration * fs))) / fs
    return amplitude * np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t ** 3 / (3 * duration ** 2)))


def sine_burst(fs: float, freq: float, on: float, off: float, amplitude: float = 1.0) -> np.ndarray:
    """``on`` s of a sine at ``freq`` Hz followed by ``off`` s of silence, (K,)."""
    t = np.arange(int(round(on * fs))) / fs
    return np.concatenate([amplitude * np.sin(2 * np.pi * freq * t), np.zeros(int(round(off * fs)))])
