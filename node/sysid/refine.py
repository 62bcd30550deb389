"""Output-error re-estimation of (B, D): the noise-robust estimator.

Plain least squares on noisy outputs is biased (errors in the regressors).
Given A and C, the free-run output of every trajectory is *linear* in B and
D (the initial states being fixed):

    y[k] = C A^k x0 + sum_{i<k} C A^(k-1-i) B u[i] + D u[k]

so minimising the free-run output error over (B, D) is a linear least-squares
problem. Its normal equations are assembled in modal coordinates
(A = V diag(lam) V^-1): each mode filters each input by a first-order
recursion, and the Gram matrix is a Hadamard product, O(K n^2) in time and
O(K n) in memory. When A is not safely diagonalizable the design matrix is
built from the Markov parameters C A^i instead (O(K p n) memory).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

MAX_EIGVEC_COND = 1e8
MAX_DESIGN_ENTRIES = 60_000_000


def markov_parameters(A: np.ndarray, C: np.ndarray, K: int) -> np.ndarray:
    """C A^i for i = 0..K-1, shape (K, p, n)."""
    p, n = C.shape
    H = np.empty((K, p, n))
    M = C.copy()
    for i in range(K):
        H[i] = M
        M = M @ A
    return H


def _modal_filter(lam: np.ndarray, U: np.ndarray) -> np.ndarray:
    """xi[k, l, j] = sum_{i<k} lam_l^(k-1-i) u_j[i]: (K, n, m) complex.

    U is real, so the filter of a pole's conjugate is the conjugate of its filter, to the
    last bit (the complex products and sums only change sign): each pair is filtered once."""
    K, m = U.shape
    xi = np.zeros((K, lam.size, m), dtype=complex)
    Uc = U.astype(complex)
    done: dict[complex, int] = {}
    for l, lam_l in enumerate(lam):
        twin = done.get(complex(lam_l).conjugate()) if lam_l.imag != 0.0 else None
        if twin is not None:
            xi[:, l, :] = xi[:, twin, :].conj()
        else:
            xi[:, l, :] = signal.lfilter([0.0, 1.0], [1.0, -lam_l], Uc, axis=0)
        done.setdefault(complex(lam_l), l)
    return xi


def _powers(lam: np.ndarray, K: int) -> np.ndarray:
    """lam^k for k = 0..K-1, (K, n) complex, by cumulative products."""
    out = np.empty((K, lam.size), dtype=complex)
    out[0] = 1.0
    if K > 1:
        out[1:] = lam[None, :]
        np.cumprod(out[1:], axis=0, out=out[1:])
    return out


def _normal_equations_modal(A, C, Ys, Us, x0s):
    lam, V = np.linalg.eig(A)
    if not np.isfinite(np.linalg.cond(V)) or np.linalg.cond(V) > MAX_EIGVEC_COND:
        return None
    return _normal_equations_eig(lam, V, np.linalg.inv(V), C, Ys, Us, x0s)[:3]


def _normal_equations_eig(lam, V, Vinv, C, Ys, Us, x0s):
    """Normal equations of (B, D) for A = V diag(lam) Vinv; also the per-trajectory
    modal quantities (filtered inputs xi, pole powers, residual after the free response)."""
    n, p, m = V.shape[0], C.shape[0], Us[0].shape[1]
    cache = []
    Vh = Vinv.conj().T
    CV = C @ V
    CVhCV = CV.conj().T @ CV
    nb = n * m
    Gxx = np.zeros((nb, nb), dtype=complex)  # sum_k conj(xi) xi^T, blocks (j, jj) of (n, n)
    Gxu = np.zeros((nb, m), dtype=complex)  # sum_k conj(xi) u^T
    Guu = np.zeros((m, m))
    gB = np.zeros(nb, dtype=complex)
    gD = np.zeros((p, m))
    rr = 0.0
    for Y, U, x0 in zip(Ys, Us, x0s):
        K = Y.shape[0]
        powers = _powers(lam, K)  # (K, n)
        R = (Y - ((powers * (Vinv @ x0)[None, :]) @ CV.T).real)  # residual after the free response
        rr += float(np.sum(R ** 2))
        xi3 = _modal_filter(lam, U)
        cache.append((xi3, powers, R))
        xi = xi3.transpose(0, 2, 1).reshape(K, nb)  # columns (j, l)
        xic = xi.conj()
        Gxx += xic.T @ xi
        Gxu += xic.T @ U
        Guu += U.T @ U
        RCV = R @ CV.conj()  # (K, n): (CV^H r(k))^T
        gB += np.einsum("kjl,kl->jl", xic.reshape(K, m, n), RCV).reshape(nb)
        gD += R.T @ U
    q = nb + p * m
    G = np.zeros((q, q), dtype=complex)
    g = np.zeros(q, dtype=complex)
    for j in range(m):
        bj = slice(j * n, (j + 1) * n)
        g[bj] = Vh @ gB[bj]
        for jj in range(m):
            bjj = slice(jj * n, (jj + 1) * n)
            G[bj, bjj] = Vh @ (CVhCV * Gxx[bj, bjj]) @ Vinv
            dj = slice(nb + jj * p, nb + (jj + 1) * p)
            G[bj, dj] = Vh @ (Gxu[bj, jj][:, None] * CV.conj().T)
        dj = slice(nb + j * p, nb + (j + 1) * p)
        g[dj] = gD[:, j]
        for jj in range(m):
            djj = slice(nb + jj * p, nb + (jj + 1) * p)
            G[dj, djj] = np.eye(p) * Guu[j, jj]
    upper = np.triu_indices(q, 1)
    G[(upper[1], upper[0])] = G[upper].conj()  # fill the D-B blocks by symmetry
    return G.real, g.real, rr, cache


def _normal_equations_markov(A, C, Ys, Us, x0s):
    n, p, m = A.shape[0], C.shape[0], Us[0].shape[1]
    K_max = max(y.shape[0] for y in Ys)
    if K_max * p * n * max(m, 1) > MAX_DESIGN_ENTRIES:
        return None
    H = markov_parameters(A, C, K_max).reshape(K_max, p * n)
    q = n * m + p * m
    G = np.zeros((q, q))
    g = np.zeros(q)
    rr = 0.0
    eye_p = np.eye(p)
    for Y, U, x0 in zip(Ys, Us, x0s):
        K = Y.shape[0]
        free = H[:K].reshape(K, p, n) @ x0
        cols = []
        for j in range(m):
            u_shift = np.concatenate([[0.0], U[:K - 1, j]])
            conv = signal.fftconvolve(H[:K], u_shift[:, None], mode="full", axes=0)[:K]
            cols.append(conv.reshape(K * p, n))
        cols += [(U[:, j][:, None, None] * eye_p[None]).reshape(K * p, p) for j in range(m)]
        X = np.hstack(cols)
        G += X.T @ X
        r = (Y - free).reshape(K * p)
        g += X.T @ r
        rr += float(r @ r)
    return G, g, rr


def refit_bd(A: np.ndarray, C: np.ndarray, Ys: list[np.ndarray], Us: list[np.ndarray],
             x0s: list[np.ndarray], rcond: float = 1e-12) -> tuple[np.ndarray, np.ndarray] | None:
    """(B, D) minimising sum over trajectories of ||Y - free_run(A, B, C, D, x0, U)||^2.

    Args:
        A: (n, n), C: (p, n) fixed.
        Ys, Us: per-trajectory outputs (K_i, p) and inputs (K_i, m).
        x0s: per-trajectory initial states (n,).
        rcond: relative eigenvalue cut of the (scaled) normal equations.

    Returns:
        B (n, m), D (p, m), or None when neither assembly applies (A defective
        and the problem too large for the Markov design matrix).
    """
    n, p, m = A.shape[0], C.shape[0], Us[0].shape[1]
    eq = _normal_equations_modal(A, C, Ys, Us, x0s)
    if eq is None:
        eq = _normal_equations_markov(A, C, Ys, Us, x0s)
    if eq is None:
        return None
    theta = _solve_normal(eq[0], eq[1], rcond)
    B = theta[: n * m].reshape(m, n).T
    D = theta[n * m:].reshape(m, p).T
    return B, D


def _solve_normal(G: np.ndarray, g: np.ndarray, rcond: float) -> np.ndarray:
    """Minimum-norm solution of the Jacobi-scaled normal equations G theta = g."""
    d = np.sqrt(np.clip(np.diag(G), 0, None))
    d[d == 0] = 1.0
    Gs = G / d[:, None] / d[None, :]
    w, Q = np.linalg.eigh((Gs + Gs.T) / 2)
    if w.max() <= 0:
        return np.zeros_like(g)
    keep = w > rcond * w.max()
    return (Q[:, keep] @ ((Q[:, keep].T @ (g / d)) / w[keep])) / d


def stabilise(A: np.ndarray) -> tuple[np.ndarray, int]:
    """Reflect poles on or outside the unit circle to 1 / conj(pole), keeping the eigenvectors.

    Returns the new A (real) and the number of poles moved. A defective A is returned as is.
    """
    lam, V = np.linalg.eig(A)
    bad = np.abs(lam) >= 1.0
    if not bad.any() or np.linalg.cond(V) > MAX_EIGVEC_COND:
        return A, 0
    lam = np.where(bad, 1.0 / np.conj(np.where(bad, lam, 1.0)) * 0.999, lam)
    return (V @ np.diag(lam) @ np.linalg.inv(V)).real, int(bad.sum())


def refine_poles(A: np.ndarray, C: np.ndarray, Ys: list[np.ndarray], Us: list[np.ndarray],
                 x0s: list[np.ndarray], maxiter: int = 60, rcond: float = 1e-12
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Output-error refinement of the poles too (variable projection).

    A = V diag(lam) V^-1 keeps the eigenvectors of the starting A (so the
    state keeps its meaning and C stays); the poles are the free parameters,
    each stable by construction (a complex pair as exp(-e^s + i w), a real
    pole as tanh(a)), and for every trial (B, D) are the linear least-squares
    optimum. Returns (A, B, D), or None when A is not safely diagonalizable.
    """
    from scipy.optimize import minimize

    A0, _ = stabilise(A)
    lam, V = np.linalg.eig(A0)
    if np.any(np.abs(lam) >= 1.0) or np.linalg.cond(V) > MAX_EIGVEC_COND:
        return None
    Vinv = np.linalg.inv(V)
    n, p, m = A.shape[0], C.shape[0], Us[0].shape[1]
    # group poles: real ones, and one representative (positive imaginary part) per pair
    real_idx = [i for i in range(n) if abs(lam[i].imag) <= 1e-12 * max(1.0, abs(lam[i]))]
    pos_idx = [i for i in range(n) if i not in real_idx and lam[i].imag > 0]
    partner: dict[int, int] = {}
    for i in pos_idx:
        cand = [j for j in range(n) if j not in real_idx and lam[j].imag < 0 and j not in partner.values()]
        partner[i] = min(cand, key=lambda j: abs(lam[j] - np.conj(lam[i])))
    if len(real_idx) + 2 * len(pos_idx) != n:
        return None

    def poles(theta: np.ndarray) -> np.ndarray:
        out = np.empty(n, dtype=complex)
        nr = len(real_idx)
        out[real_idx] = np.tanh(theta[:nr])
        for k, i in enumerate(pos_idx):
            s, w = theta[nr + 2 * k], theta[nr + 2 * k + 1]
            z = np.exp(-np.exp(s) + 1j * w)  # |z| = exp(-e^s) < 1 for every s
            out[i], out[partner[i]] = z, np.conj(z)
        return out

    start = [np.arctanh(np.clip(lam[i].real, -0.999999, 0.999999)) for i in real_idx]
    for i in pos_idx:
        start += [np.log(-np.log(np.clip(abs(lam[i]), 1e-12, 1 - 1e-12))), float(np.angle(lam[i]))]
    theta0 = np.array(start)
    scale = float(sum(np.sum(y ** 2) for y in Ys)) or 1.0

    CV = C @ V
    nr = len(real_idx)

    def cost_grad(theta):
        lam_t = poles(theta)
        G, g, rr, cache = _normal_equations_eig(lam_t, V, Vinv, C, Ys, Us, x0s)
        th = _solve_normal(G, g, rcond)
        B = th[: n * m].reshape(m, n).T
        D = th[n * m:].reshape(m, p).T
        bt = Vinv @ B  # (n, m) modal input gains
        h = np.zeros(n, dtype=complex)
        for (xi, powers, R), U, x0 in zip(cache, Us, x0s):
            K = U.shape[0]
            z0 = Vinv @ x0
            forced = np.einsum("knj,nj->kn", xi, bt)  # (K, n) modal forced responses
            r = R - (forced @ CV.T).real - U @ D.T  # full residual (K, p)
            k = np.arange(K)[:, None]
            prev = np.vstack([np.zeros((1, n), dtype=complex), powers[:-1]])
            d = k * prev * z0[None, :]
            for l in range(n):
                dxi = signal.lfilter([0.0, 1.0], [1.0, -lam_t[l]], xi[:, l, :], axis=0)
                d[:, l] += dxi @ bt[l]
            h += np.einsum("kp,pl,kl->l", r, CV, d)
        grad = np.zeros_like(theta)
        grad[:nr] = -2.0 * h[real_idx].real * (1.0 - lam_t[real_idx].real ** 2)
        for q, i in enumerate(pos_idx):
            s_ = theta[nr + 2 * q]
            dz_ds = -np.exp(s_) * lam_t[i]
            dz_dw = 1j * lam_t[i]
            grad[nr + 2 * q] = -4.0 * (h[i] * dz_ds).real
            grad[nr + 2 * q + 1] = -4.0 * (h[i] * dz_dw).real
        c = (rr - 2 * g @ th + th @ G @ th) / scale
        return c, grad / scale, (lam_t, B, D)

    c0 = cost_grad(theta0)[0]
    res = minimize(lambda t: cost_grad(t)[:2], theta0, jac=True, method="L-BFGS-B",
                   options={"maxiter": maxiter})
    theta = res.x if np.isfinite(res.fun) and res.fun <= c0 else theta0
    lam_t, B, D = cost_grad(theta)[2]
    return (V @ np.diag(lam_t) @ Vinv).real, B, D
