"""A veering group's block fitted jointly over the parameter samples.

Interpolating each sample's block (A'^2, A' B', C' in a common basis) passes through every
sample's identification error, and where two modes nearly cross the mixing at the new
parameter is inferred from samples whose shapes are nearly pure: their pole errors are
amplified there (about fourfold at a 3 % gap with 2 % damping). Here the block is one model of
the parameter instead, X(t) = sum_k t^e_k X_k (the monomials of total degree <= 2 that the
samples' parameters determine) with Y and C the same at every sample, fitted by least squares
to all samples' frequency responses at once (each sample's relative error over a grid around
its poles): the pole and shape errors of the samples are weighed by what they do to the
response, and the errors that no smooth block explains are averaged out. For a stiffness-like
parameter -X is the stiffness matrix in the common basis (plus a damping term of the order
zeta), Y the force distribution and C the output shapes; the quadratic term takes up the
damping's curvature. The block is in the modal variables X = A'^2, Y = A' B' whatever the
ROM's scheme: with A' and B' (the direct scheme's) fixed B' would miss that a
force-to-displacement residue scales as 1 / w.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

# Levenberg-Marquardt steps at most (each a finite-difference Jacobian of ~80 responses): the fit
# gains little after a few dozen, and a leave-one-sample-out validation runs one per fold
MAX_NFEV = 20
GRID = np.tan(np.linspace(-1.4, 1.4, 24))  # frequencies about a pole, in its half-power half-widths


@dataclass(frozen=True)
class JointBlock:
    """X(t) (g, g) = sum_k prod(t ** exps[k]) X[k] = A'^2, Y (g, m) = A' B', C (p, g) = C',
    t = (p - center) / scale (q,).

    One undamped mode of w^2 = 4 + 2 p (rad/s)^2, unit force (A' B' = 1 / 2), unit output:

    >>> b = JointBlock(np.array([[[-4.0]], [[-2.0]]]) + 0j, np.array([[0.5 + 0j]]), np.array([[1.0 + 0j]]),
    ...                exponents(np.array([[0.0], [1.0]])), np.zeros(1), np.ones(1))
    >>> s, R = modes(*b.at(np.array([6.0])))
    >>> s.round(6), R.ravel().round(6)    # w = 4 rad/s, residue 1 / (2 i w)
    (array([0.+4.j]), array([0.-0.125j]))
    """

    X: np.ndarray  # (k, g, g) complex
    Y: np.ndarray  # (g, m) complex
    C: np.ndarray  # (p, g) complex
    exps: np.ndarray  # (k, q) int
    center: np.ndarray  # (q,)
    scale: np.ndarray  # (q,)

    def at(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, Y, C at parameter value p (q,)."""
        return _eval(self.X, _monomials((np.asarray(p, float) - self.center) / self.scale, self.exps)), \
            self.Y, self.C


def _monomials(t: np.ndarray, exps: np.ndarray) -> np.ndarray:
    """prod_j t_j ** exps[k, j] (k,) for t (q,)."""
    return np.prod(t[None, :] ** exps, axis=1)


def _eval(coefs: np.ndarray, mono: np.ndarray) -> np.ndarray:
    return np.einsum("k,kab->ab", mono, coefs)


def exponents(T: np.ndarray) -> np.ndarray:
    """Exponents (k, q) of the monomials of total degree <= 2 in q parameters that the samples'
    scaled parameters T (n, q) determine: by degree, each kept when it is not a linear
    combination of those before it over the samples (a parameter with two values has no square).

    >>> exponents(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0], [1.0, 1.0]])).tolist()
    [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1]]
    """
    q = T.shape[1]
    cands = sorted((e for e in itertools.product(range(3), repeat=q) if sum(e) <= 2),
                   key=lambda e: (sum(e), [-x for x in e]))
    kept: list[tuple[int, ...]] = []
    for e in cands:
        M = np.array([[_monomials(t, np.array([c]))[0] for c in (*kept, e)] for t in T])
        if np.linalg.matrix_rank(M, tol=1e-8 * max(1.0, float(np.abs(M).max()))) == len(kept) + 1:
            kept.append(e)
    return np.array(kept, dtype=int).reshape(-1, q)


def modes(X: np.ndarray, Y: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper-half-plane poles (g,) and residues (g, p, m) of the block X = A'^2, Y = A' B', C = C'
    (least squares for a defective X)."""
    ev, V = np.linalg.eig(X)
    s = 1j * np.sqrt(-ev)
    Bm = (np.linalg.pinv(V) @ Y) / s[:, None]
    return s, np.einsum("pj,jm->jpm", C @ V, Bm)


def response(s: np.ndarray, R: np.ndarray, w: np.ndarray) -> np.ndarray:
    """H(i w) (L, p, m) of the real system with upper-half-plane modes s (g,), R (g, p, m), w (L,) rad/s."""
    jw = 1j * w[:, None]
    return np.einsum("lj,jpm->lpm", 1.0 / (jw - s[None, :]), R) \
        + np.conj(np.einsum("lj,jpm->lpm", 1.0 / (-jw - s[None, :]), R))


def grid(s: np.ndarray) -> np.ndarray:
    """Frequencies (rad/s) about every pole of s (any shape): +-5.8 half-power half-widths."""
    s = np.ravel(s)
    w = np.unique((np.abs(s.imag)[:, None] + np.abs(s.real)[:, None] * GRID[None, :]).ravel())
    return w[w > 0]


def fit_joint(s: np.ndarray, R: np.ndarray, P: np.ndarray, scale: np.ndarray, X: np.ndarray,
              Y: np.ndarray, C: np.ndarray, modal: bool) -> JointBlock | None:
    """The block of a group fitted to all samples' responses: s (n, g) and R (n, g, p, m) the
    samples' modes, P (n, q) their parameters, ``scale`` (q,), X (n, g, g), Y (n, g, m),
    C (n, p, g) their blocks in a common basis, A'^2, A' B', C' (``modal``) or A', B', C' (the
    start: X regressed on the monomials, Y and C averaged). None when the fit fails."""
    n, g = s.shape
    if not modal:
        X, Y = X @ X, X @ Y
    center = P.mean(axis=0)
    exps = exponents((P - center) / scale)
    M = np.array([_monomials((P[i] - center) / scale, exps) for i in range(n)])  # (n, k)
    k = len(exps)
    X0 = np.linalg.lstsq(M, X.reshape(n, -1), rcond=None)[0].reshape(k, g, g)
    start = [X0, Y.mean(axis=0), C.mean(axis=0)]
    shapes = [a.shape for a in start]
    sizes = [a.size for a in start]
    w = grid(s)
    H = np.array([response(s[i], R[i], w) for i in range(n)])
    norm = np.linalg.norm(H.reshape(n, -1), axis=1)[:, None, None, None]

    def unpack(x: np.ndarray) -> list[np.ndarray]:
        z = x[:len(x) // 2] + 1j * x[len(x) // 2:]
        return [a.reshape(sh) for a, sh in zip(np.split(z, np.cumsum(sizes)[:-1]), shapes)]

    def residual(x: np.ndarray) -> np.ndarray:
        Xk, Yc, Cc = unpack(x)
        Hm = np.array([response(*modes(_eval(Xk, M[i]), Yc, Cc), w) for i in range(n)])
        r = ((Hm - H) / norm).ravel()
        return np.r_[r.real, r.imag]

    z0 = np.concatenate([a.ravel() for a in start])
    try:
        with np.errstate(all="ignore"):
            sol = least_squares(residual, np.r_[z0.real, z0.imag], method="lm", x_scale="jac",
                                max_nfev=MAX_NFEV)
    except (np.linalg.LinAlgError, ValueError):
        return None
    if not np.all(np.isfinite(sol.fun)):
        return None
    Xk, Yc, Cc = unpack(sol.x)
    return JointBlock(Xk, Yc, Cc, exps, center, scale)
