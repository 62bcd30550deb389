"""Discrete-time linear state-space model shared by every identification method.

    x[k+1] = A x[k] + B u[k]
    y[k]   = C x[k] + D u[k]

Arrays are time-major: inputs ``U`` are (K, m), outputs (K, p), states (K, n).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np
from scipy import linalg

from node.sysid.validation import as_matrix


@dataclass(frozen=True)
class PoleResidue:
    """Pole-residue form of a discrete-time transfer matrix (chapter 6).

    H(z) = D + sum_i R_i / (z - poles_i), with R_i (p, m) complex.

    Attributes:
        poles: (n,) complex poles.
        residues: (n, p, m) complex residues, one matrix per pole.
        D: (p, m) direct feed-through.
        dt: sample time in seconds.
    """

    poles: np.ndarray
    residues: np.ndarray
    D: np.ndarray
    dt: float

    def frequency_response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """H at z = exp(i 2 pi f dt); returns (L, p, m) complex."""
        z = np.exp(2j * np.pi * np.asarray(freqs_hz, dtype=float) * self.dt)
        terms = self.residues[None, :, :, :] / (z[:, None, None, None] - self.poles[None, :, None, None])
        return terms.sum(axis=1) + self.D[None]

    def to_statespace(self) -> StateSpace:
        """Real state-space realisation (modal form, conjugate pairs as real 2x2 blocks).

        Each residue R_i is factored by its SVD into rank-r outer products; a real
        pole uses real blocks, a complex pair a real 2x2 block per rank term.
        """
        poles, R = self.poles, self.residues
        p, m = self.D.shape
        used = np.zeros(len(poles), dtype=bool)
        blocks_a: list[np.ndarray] = []
        blocks_b: list[np.ndarray] = []
        blocks_c: list[np.ndarray] = []
        for i, lam in enumerate(poles):
            if used[i]:
                continue
            used[i] = True
            is_real = abs(lam.imag) <= 1e-12 * max(1.0, abs(lam))
            u_, s_, vh_ = np.linalg.svd(R[i].real if is_real else R[i])
            rank = max(1, int(np.sum(s_ > s_[0] * 1e-14))) if s_[0] > 0 else 1
            if is_real:
                for r in range(rank):
                    c_col = (u_[:, r] * s_[r]).real
                    b_row = vh_[r].real
                    blocks_a.append(np.array([[lam.real]]))
                    blocks_b.append(b_row[None, :])
                    blocks_c.append(c_col[:, None])
                continue
            # find and consume the conjugate partner
            cand = np.where(~used)[0]
            if cand.size:
                j = cand[np.argmin(np.abs(poles[cand] - np.conj(lam)))]
                used[j] = True
            a, b = lam.real, lam.imag
            for r in range(rank):
                c = u_[:, r] * s_[r]  # (p,) complex
                v = vh_[r]  # (m,) complex
                # R/(z-lam) + conj(R)/(z-conj(lam)) realised with state [Re, Im]
                blocks_a.append(np.array([[a, -b], [b, a]]))
                blocks_b.append(np.vstack([v.real, v.imag]))
                blocks_c.append(np.column_stack([2 * c.real, -2 * c.imag]))
        if not blocks_a:
            return StateSpace(np.zeros((0, 0)), np.zeros((0, m)), np.zeros((p, 0)), self.D.copy(), self.dt)
        A = linalg.block_diag(*blocks_a)
        B = np.vstack(blocks_b)
        C = np.hstack(blocks_c)
        return StateSpace(A, B, C, self.D.real.copy(), self.dt)


@dataclass(frozen=True)
class StateSpace:
    """A discrete-time LTI model (A, B, C, D) with sample time ``dt`` (s).

    Shapes: A (n, n), B (n, m), C (p, n), D (p, m).

    >>> ss = StateSpace(np.array([[0.9, 0.2], [0.0, 0.5]]), np.array([[1.0], [0.5]]),
    ...                 np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    >>> np.sort(ss.poles().real), ss.is_stable()
    (array([0.5, 0.9]), True)
    >>> ss.simulate(np.ones((3, 1)))[:, 0]  # from rest: y = C x, x[k+1] = A x[k] + B u[k]
    array([0., 1., 2.])
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float = 1.0

    def __post_init__(self) -> None:
        # one memory layout for every model, so that a model reloaded from a file computes
        # bit for bit what the fitted one did (BLAS rounding depends on the layout)
        for name in ("A", "B", "C", "D"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=float))
        n, m, p = self.A.shape[0], self.B.shape[1], self.C.shape[0]
        if self.A.shape != (n, n) or self.B.shape != (n, m) or self.C.shape != (p, n) \
                or self.D.shape != (p, m):
            raise ValueError(
                f"inconsistent state-space shapes: A {self.A.shape}, B {self.B.shape}, "
                f"C {self.C.shape}, D {self.D.shape}")
        if not self.dt > 0:
            raise ValueError(f"sample time dt must be positive, got {self.dt}")

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    def poles(self) -> np.ndarray:
        """Eigenvalues of A, (n,) complex (discrete-time, |z| < 1 is stable)."""
        return np.linalg.eigvals(self.A)

    def spectral_radius(self) -> float:
        return float(np.max(np.abs(self.poles()))) if self.n_states else 0.0

    def is_stable(self, margin: float = 0.0) -> bool:
        """True when every pole lies strictly inside the circle of radius 1 - margin."""
        return self.spectral_radius() < 1.0 - margin

    @overload
    def simulate(self, U: np.ndarray, x0: np.ndarray | None = None,
                 return_states: Literal[False] = False) -> np.ndarray: ...

    @overload
    def simulate(self, U: np.ndarray, x0: np.ndarray | None,
                 return_states: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def simulate(self, U: np.ndarray, x0: np.ndarray | None = None, *,
                 return_states: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...

    def simulate(self, U: np.ndarray, x0: np.ndarray | None = None,
                 return_states: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Free-run response to inputs ``U`` (K, m) from state ``x0`` (n,), zero if None.

        Returns Y (K, p); with ``return_states`` also X (K + 1, n), X[k] the
        state before sample k is applied (X[K] is the state after the last).
        """
        U = as_matrix(U, "U", cols=self.n_inputs)
        n = self.n_states
        x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).reshape(n)
        K = U.shape[0]
        X = np.empty((K + 1, n))
        X[0] = x
        BU = U @ self.B.T
        A = self.A
        for k in range(K):
            X[k + 1] = A @ X[k] + BU[k]
        Y = X[:K] @ self.C.T + U @ self.D.T
        return (Y, X) if return_states else Y

    def frequency_response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """H(f) = C (zI - A)^-1 B + D at z = exp(i 2 pi f dt); returns (L, p, m) complex."""
        z = np.exp(2j * np.pi * np.asarray(freqs_hz, dtype=float) * self.dt)
        n = self.n_states
        # Hessenberg-free but stable: modal form when diagonalizable, else solve per point.
        out = np.empty((z.size, self.n_outputs, self.n_inputs), dtype=complex)
        eye = np.eye(n)
        for i, zi in enumerate(z):
            out[i] = self.C @ np.linalg.solve(zi * eye - self.A, self.B) + self.D
        return out

    def to_pole_residue(self) -> PoleResidue:
        """Modal decomposition: residues R_i = (C v_i)(w_i^H B) for each eigenpair.

        Requires a diagonalizable A (raises ValueError when the eigenvector
        matrix is numerically singular).
        """
        lam, V = np.linalg.eig(self.A)
        cond = np.linalg.cond(V) if self.n_states else 1.0
        if not np.isfinite(cond) or cond > 1e12:
            raise ValueError(f"A is not diagonalizable to working precision (cond(V) = {cond:.3g})")
        W = np.linalg.inv(V)
        CV = self.C @ V  # (p, n)
        WB = W @ self.B  # (n, m)
        residues = CV.T[:, :, None] * WB[:, None, :]  # (n, p, m)
        return PoleResidue(lam, residues, self.D.astype(complex), self.dt)

    def modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Poles (n,) and output mode shapes C v_i, (p, n) complex (for MAC)."""
        lam, V = np.linalg.eig(self.A)
        return lam, self.C @ V
