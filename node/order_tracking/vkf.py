"""Second-generation Vold-Kalman filter (VKF): joint envelopes of several orders.

Model (x: (K,) real signal at fs Hz; order k with reference angle theta_k (rad)):

    data equation        x[n] = sum_k a_k[n] cos(p_k theta_k[n] + phi_k[n]) + e[n]
                              = sum_k u_k[n] cos(Θ_k[n]) - v_k[n] sin(Θ_k[n]) + e[n]
    structural equation  u_k[n] - 2 u_k[n+1] + u_k[n+2] = eps (same for v_k)

with Θ_k = p_k theta_k and the complex envelope z_k = u_k + i v_k = a_k e^{i phi_k} (the phase
returned is the lag -phi_k in degrees, ``node.contract.vector.order_lags``).
Writing the envelope as two real parts (instead of fitting x with a complex
exponential only) models the negative-frequency half of each real order exactly, so
slow orders and near-DC order frequencies carry no image error.

All envelopes are estimated jointly by minimising

    J = ||x - Phi z||^2 + sum_k (r_k^2 / 2) (||D u_k||^2 + ||D v_k||^2),

D the (K-2, K) second-difference matrix. The normal equations
(Phi^T Phi + D^T D ⊗ diag(r^2)) z = Phi^T x are assembled with scipy.sparse with the
unknowns interleaved per sample (index n*m + j, m = 2*n_orders), which makes the
matrix symmetric positive definite and banded with half-bandwidth 2m; it is solved
by a banded Cholesky factorisation (scipy.linalg.cholesky_banded, O(K m^3)) or, on
request, by a sparse LU (scipy.sparse.linalg.splu). The condition number grows like
8 r^2, so the solution is polished by iterative refinement with the residual
evaluated in extended precision (numpy.longdouble): on a noise-free steady signal
(fs = 4096 Hz, B = 2 Hz) two refinement steps bring the envelope error from ~1e-5
to ~1e-15. Bandwidths with 8 r^2 > 1e15 (B/fs below ~1.5e-4) are refused.
Because the orders share the data equation, orders that cross (different reference
shafts) or lie close are separated jointly instead of leaking into each other's
envelopes.

Bandwidth -> weighting factor (Vold & Leuridan 1993; Tůma, ICSV12 2005): for one
order, the estimated envelope is the demodulated signal passed through
H(w) = 1 / (1 + r^2 |1 - e^{-iw}|^4) = 1 / (1 + 16 r^2 sin^4(w/2)),
w = 2 pi f / fs the frequency offset from the order line. (cos^2 and sin^2 of the
carrier average 1/2, so the real data equation weighs each envelope part by 1/2
on average; the structural weight r^2/2 in J makes H the same as in Tůma's complex
formulation.) Requiring |H| = 1/sqrt(2)
(-3 dB) at f = B/2, B the full two-sided -3 dB bandwidth in Hz, gives

    r = sqrt(sqrt(2) - 1) / (4 sin^2(pi B / (2 fs))).

A linear envelope trend passes unbiased (its second difference is zero). The default
B = 2 Hz (+-1 Hz around each order line) follows amplitude changes of a run-up
resonance lasting a second or more and rejects broadband noise; widen it for fast
transients, narrow it for noisier data (r grows as 1/B^2; see the conditioning limit
above).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded
from scipy.sparse.linalg import splu

from node.contract.vector import order_lags

from ._checks import (
    check_below_nyquist,
    check_distinct_tracks,
    check_fs,
    check_orders,
    check_rpm,
    check_signal,
)
from .angle import shaft_revolutions
from .result import OrderTrack

DEFAULT_BANDWIDTH_HZ = 2.0
_SOLVERS = ("banded", "spsolve")
_REFINEMENT_STEPS = 2
_MAX_CONDITION = 1e15  # 8 r^2 beyond this: refinement stalls, then Cholesky fails


def weighting_factor(bandwidth_hz: float | np.ndarray, fs: float) -> np.ndarray:
    """VKF weight r for a full two-sided -3 dB bandwidth in Hz (2-pole filter)."""
    b = np.asarray(bandwidth_hz, dtype=float)
    return np.sqrt(np.sqrt(2.0) - 1.0) / (4.0 * np.sin(np.pi * b / (2.0 * fs)) ** 2)


def _min_bandwidth(fs: float) -> float:
    """Narrowest bandwidth (Hz) whose weight stays below the conditioning limit."""
    r_max = np.sqrt(_MAX_CONDITION / 8.0)
    return float(2.0 * fs / np.pi * np.arcsin(np.sqrt(np.sqrt(np.sqrt(2.0) - 1.0)
                                                        / (4.0 * r_max))))


def _carriers(rpm: np.ndarray, fs: float, orders: np.ndarray) -> np.ndarray:
    """(K, 2*n_orders) regressors [cos Θ_0, -sin Θ_0, cos Θ_1, ...]."""
    rev = shaft_revolutions(rpm, fs)
    if rev.ndim == 1:
        rev = rev[:, None]
    theta = 2.0 * np.pi * rev * orders[None, :]
    phi = np.empty((theta.shape[0], 2 * orders.size))
    phi[:, 0::2] = np.cos(theta)
    phi[:, 1::2] = -np.sin(theta)
    return phi


def assemble_normal_equations(x: np.ndarray, phi: np.ndarray,
                              r: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Sparse normal matrix (K*m, K*m) and right-hand side (K*m,), m = phi.shape[1].

    ``r`` (m,) is the weighting factor per unknown component (u_k and v_k share r_k);
    the structural term is weighted by r^2 / 2 (see the module docstring).
    """
    k, m = phi.shape
    rows = np.repeat(np.arange(k), m)
    cols = np.arange(k * m)
    design = sp.csr_matrix((phi.ravel(), (rows, cols)), shape=(k, k * m))
    second_diff = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(k - 2, k), format="csr")
    smooth = sp.kron(second_diff.T @ second_diff, sp.diags(0.5 * r**2), format="csr")
    normal = (design.T @ design + smooth).tocsr()
    rhs = (phi * x[:, None]).ravel()
    return normal, rhs


def _lower_band(matrix: sp.spmatrix, half_bandwidth: int) -> np.ndarray:
    """Lower banded storage ab[i - j, j] = A[i, j] for solveh_banded."""
    lower = sp.tril(matrix, format="csr")
    lower.sum_duplicates()  # no-op on canonical CSR; guarantees unique entries
    lower = lower.tocoo()
    ab = np.zeros((half_bandwidth + 1, matrix.shape[0]))
    ab[lower.row - lower.col, lower.col] = lower.data
    return ab


def _residual(x: np.ndarray, phi: np.ndarray, r: np.ndarray, z: np.ndarray) -> np.ndarray:
    """b - A z of the normal equations, evaluated in extended precision."""
    ld = np.longdouble
    zz = z.reshape(phi.shape).astype(ld)
    ph = phi.astype(ld)
    fit = np.sum(ph * zz, axis=1)
    res = ph * (x.astype(ld) - fit)[:, None]
    d2 = zz[:-2] - 2 * zz[1:-1] + zz[2:]
    dtd = np.zeros_like(zz)
    dtd[:-2] += d2
    dtd[1:-1] -= 2 * d2
    dtd[2:] += d2
    res -= dtd * (ld(0.5) * r.astype(ld) ** 2)
    return res.astype(float).ravel()


def solve_normal_equations(x: np.ndarray, phi: np.ndarray, r: np.ndarray,
                           solver: str = "banded") -> np.ndarray:
    """Envelope parts z (K*m,) interleaved per sample, refined in extended precision."""
    normal, rhs = assemble_normal_equations(x, phi, r)
    m = phi.shape[1]
    try:
        if solver == "banded":
            factor = cholesky_banded(_lower_band(normal, 2 * m), lower=True,
                                     check_finite=False)

            def solve(b: np.ndarray) -> np.ndarray:
                return cho_solve_banded((factor, True), b, check_finite=False)
        else:
            solve = splu(normal.tocsc()).solve
    except (LinAlgError, RuntimeError) as exc:
        raise ValueError(
            "VKF system is numerically singular; widen bandwidth_hz or lower fs"
        ) from exc
    z = solve(rhs)
    for _ in range(_REFINEMENT_STEPS):
        z += solve(_residual(x, phi, r, z))
    return z


def vkf_orders(x: object, fs: float, rpm: object, orders: object, *,
               bandwidth_hz: float | np.ndarray = DEFAULT_BANDWIDTH_HZ,
               solver: str = "banded") -> OrderTrack:
    """Order amplitude and phase by the joint second-generation Vold-Kalman filter.

    Parameters
    ----------
    x : (K,) vibration signal (any unit; amplitudes come out in the same unit).
    fs : sampling rate of x and rpm, Hz.
    rpm : reference speed in rev/min, (K,) shared by all orders, or (K, n_orders) one
        reference shaft per order (e.g. LP and HP spool orders that cross).
        Any finite sign; the shaft angle is integrated from it (0 at the first sample).
    orders : (n_orders,) orders to track; the same order may repeat on different
        speed references (columns of a 2-D rpm).
    bandwidth_hz : full two-sided -3 dB bandwidth B in Hz, scalar or (n_orders,);
        0 < B < fs/2. See the module docstring for the mapping to r.
    solver : "banded" (Cholesky on the band, default) or "spsolve" (sparse LU);
        both are followed by extended-precision iterative refinement.

    Returns
    -------
    OrderTrack with times (K,) = n/fs s, amplitudes and phases (lags, degrees in
    [-180, 180)) (K, n_orders), rpm as given ((K,) or (K, n_orders)).
    """
    fs = check_fs(fs)
    sig = check_signal(x)
    ords = check_orders(orders, distinct=False)
    speed = check_rpm(rpm, sig.size, n_orders=ords.size, positive=False)
    check_distinct_tracks(ords, speed)
    check_below_nyquist(ords, speed, fs)
    bw = np.broadcast_to(np.asarray(bandwidth_hz, dtype=float), ords.shape) \
        if np.ndim(bandwidth_hz) == 0 or np.shape(bandwidth_hz) == ords.shape else None
    if bw is None:
        raise ValueError(
            f"bandwidth_hz must be a scalar or have shape ({ords.size},), "
            f"got shape {np.shape(bandwidth_hz)}"
        )
    if not np.all(np.isfinite(bw)) or np.any(bw <= 0.0) or np.any(bw >= fs / 2.0):
        raise ValueError(f"bandwidth_hz must lie in (0, fs/2 = {fs / 2:g}) Hz, got {bw}")
    if solver not in _SOLVERS:
        raise ValueError(f"solver must be one of {_SOLVERS}, got {solver!r}")

    r = np.repeat(weighting_factor(bw, fs), 2)
    if 8.0 * float(r.max()) ** 2 > _MAX_CONDITION:
        raise ValueError(
            f"bandwidth_hz={bw.min():g} is too narrow for fs={fs:g} Hz (ill-conditioned "
            f"VKF system); use >= {_min_bandwidth(fs):.3g} Hz or decimate the signal"
        )
    phi = _carriers(speed, fs, ords)
    z = solve_normal_equations(sig, phi, r, solver)
    env = z.reshape(sig.size, ords.size, 2)
    cplx = env[..., 0] + 1j * env[..., 1]
    return OrderTrack(times=np.arange(sig.size) / fs, amplitudes=np.abs(cplx),
                      phases=order_lags(cplx), orders=ords, rpm=speed, method="vkf")
