"""Parametric reduced-order models by pole-residue interpolation (chapter 6, eq. 6.7-6.11).

A library of models is fitted at parameter samples, each put in pole-residue form,
its dominant modes matched across the samples, and poles and residues interpolated
to a new parameter value.

Each discrete-time mode (pole z, residue R_z) is taken to its exact zero-order-hold
continuous equivalent s = ln(z) / dt, R_s = R_z s / (z - 1) (the continuous mode whose
ZOH discretisation is that discrete mode), interpolated there, and mapped back. In the
s-plane a stiffness-like parameter moves the physical quantities w^2 = |s|^2 and
2 zeta w = -2 Re s almost linearly, and a force-to-displacement residue scales as
1 / w, so R_s w carries only the mode shape; the discrete z and R_z bend all of these.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from sklearn.base import BaseEstimator

from node.sysid.memo import ContentMemo
from node.sysid.metrics import mac
from node.sysid.observer import estimate_state
from node.sysid.statespace import PoleResidue, StateSpace
from node.sysid.validation import as_matrix

log = logging.getLogger(__name__)

SCHEMES = ("modal", "direct")
WEIGHTS = ("auto", "lagrange", "linear", "rbf", "regress", "mean")
FORMAT = 1  # version of ``to_arrays``


@dataclass(frozen=True)
class _Modes:
    """The candidate modes of one sample in continuous form: s (k,), R_s (k, p, m), peak share (k,)."""

    s: np.ndarray
    R: np.ndarray
    share: np.ndarray


def _pole_residue(ss: StateSpace, fast: float = 0.05, points: int = 8) -> PoleResidue:
    """The modes of ``ss`` with |z| > ``fast`` in pole-residue form, residues by contour integrals.

    Unlike :meth:`StateSpace.to_pole_residue` it needs no diagonalisable A: DMD models of
    rank-deficient lifts hold defective clusters (split Jordan blocks, often with an
    uncontrollable or unobservable partner) whose eigenvectors give huge, cancelling residues.
    Eigenvalues closer than 1e-6 (1 + |z|) are one pole; its residue is the trapezoidal rule
    for (1 / 2 pi i) contour integral of H around it on ``points`` points of a small circle
    that holds no other pole: exact to rounding for a simple pole of H.
    """
    lam = np.linalg.eigvals(ss.A)
    poles: list[complex] = []
    for z in lam[np.argsort(-np.abs(lam))]:
        if abs(z) > fast and all(abs(z - q) > 1e-6 * (1 + abs(z)) for q in poles):
            poles.append(complex(z))
    P = np.array(poles, dtype=complex)
    ring = np.exp(2j * np.pi * np.arange(points) / points)
    eye = np.eye(ss.n_states)
    R = np.empty((len(P), ss.n_outputs, ss.n_inputs), dtype=complex)
    for i, z in enumerate(P):
        others = np.abs(lam - z)
        near = others[others > 1e-6 * (1 + abs(z))]
        radius = min(1e-4 * (1 + abs(z)), 0.25 * (near.min() if near.size else 1.0))
        radius = max(radius, 10 * float(np.max(others[others <= 1e-6 * (1 + abs(z))])))
        R[i] = sum(radius * w * (ss.C @ np.linalg.solve((z + radius * w) * eye - ss.A, ss.B))
                   for w in ring) / points
    return PoleResidue(P, R, ss.D.astype(complex), ss.dt)


def static_gain(ss: StateSpace) -> np.ndarray:
    """Static gain (p, m) of a discrete model: C (I - A)^-1 B + D (inf where A has a pole at 1)."""
    try:
        return np.asarray(ss.C @ np.linalg.solve(np.eye(ss.n_states) - ss.A, ss.B) + ss.D)
    except np.linalg.LinAlgError:
        return np.full(ss.D.shape, np.inf)


_FORMS: ContentMemo[tuple[PoleResidue, np.ndarray]] = ContentMemo(512)


def _modal_form(ss: StateSpace) -> tuple[PoleResidue, np.ndarray]:
    """``_pole_residue`` and ``static_gain`` of ``ss``, memoised on its matrices: a
    leave-one-run-out CV builds a ROM per fold from the same library models."""
    return _FORMS.get([np.array([ss.dt]), ss.A, ss.B, ss.C, ss.D],
                      lambda: (_pole_residue(ss), static_gain(ss)))


def _modes(pr: PoleResidue, real: bool) -> _Modes:
    """Complex modes (upper half plane; ``real`` False) or real modes with 0 < z < 1 (``real`` True)."""
    z, Rz = pr.poles, pr.residues
    is_real = np.abs(z.imag) <= 1e-10 * np.maximum(1.0, np.abs(z))
    keep = (is_real & (z.real > 0)) if real else (~is_real & (z.imag > 0))
    # peak gain of each mode, ||R|| / (1 - |z|) (its response at its own frequency; the distance
    # to the circle floored at 1e-9); the H2 norm ||R||^2 / (1 - |z|^2) would rank broadband,
    # heavily damped modes fitted to noise above lightly damped physical ones
    peak = np.linalg.norm(Rz, axis=(1, 2)) / np.maximum(1.0 - np.abs(z), 1e-9)
    total = float(np.sum(peak[~is_real | (z.real > 0)])) or 1.0
    z, Rz = (z[keep].real + 0j, Rz[keep].real + 0j) if real else (z[keep], Rz[keep])
    s = np.log(z) / pr.dt
    near1 = np.abs(z - 1.0) < 1e-12
    ratio = np.where(near1, 1.0 / pr.dt, s / np.where(near1, 1.0, z - 1.0))  # s / (z - 1) -> 1 / dt
    return _Modes(s, Rz * ratio[:, None, None], peak[keep] / total)


def _directions(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leading output (p, k) and input (m, k) directions of residues (k, p, m)."""
    u, _, vh = np.linalg.svd(R)
    return u[:, :, 0].T, vh[:, 0, :].conj().T


def _cost(a: _Modes, b: _Modes, mac_weight: float) -> np.ndarray:
    """(k_a, k_b): relative s-plane distance + mac_weight (1 - MAC_out MAC_in)."""
    dist = np.abs(a.s[:, None] - b.s[None, :]) / np.maximum(np.abs(a.s)[:, None], np.abs(b.s)[None, :])
    ua, va = _directions(a.R)
    ub, vb = _directions(b.R)
    return dist + mac_weight * (1.0 - mac(ua, ub) * mac(va, vb))


def _tree(P: np.ndarray) -> list[tuple[int, int]]:
    """(child, parent) edges of the minimum spanning tree over the samples (Prim, from sample 0),
    in the order they are added: each sample is matched to its nearest already matched one."""
    n = len(P)
    d = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=2)
    done = [0]
    edges: list[tuple[int, int]] = []
    while len(done) < n:
        rest = [i for i in range(n) if i not in done]
        sub = d[np.ix_(done, rest)]
        r, c = np.unravel_index(int(np.argmin(sub)), sub.shape)
        edges.append((rest[c], done[r]))
        done.append(rest[c])
    return edges


def _model_of(est: Any) -> StateSpace:
    """A fitted estimator's state space (``model_``, else its A, B, C, D, dt)."""
    return est.model_ if hasattr(est, "model_") else StateSpace(est.A, est.B, est.C, est.D, est.dt)


def _as_pairs(sample: Any) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One (Y, U) pair, or a list of pairs, to lists of Y and U."""
    if isinstance(sample, tuple) and len(sample) == 2 and not isinstance(sample[0], tuple):
        return [sample[0]], [sample[1]]
    pairs = list(sample)
    if not pairs or any(not (isinstance(p, tuple) and len(p) == 2) for p in pairs):
        raise ValueError("each sample must be a (Y, U) pair or a non-empty list of (Y, U) pairs")
    return [p[0] for p in pairs], [p[1] for p in pairs]


class ParametricModel:
    """A model interpolated by :meth:`ParametricROM.at`: a real, stable modal state space.

    ``A``, ``B``, ``C``, ``D`` and ``model_`` (:class:`StateSpace`); ``simulate`` seeds the
    state from a measured history by least squares over its last samples (the observer).
    """

    seed_rcond = 1e-4

    def __init__(self, model: StateSpace) -> None:
        self.model_ = model
        self.A, self.B, self.C, self.D = model.A, model.B, model.C, model.D

    def initial_state(self, history: Any) -> np.ndarray:
        """State after ``history``: (Y1, U1), Y1 alone (inputs taken as zero) or None (rest)."""
        ss = self.model_
        if history is None:
            return np.zeros(ss.n_states)
        Y1, U1 = history if isinstance(history, tuple) else (history, None)
        Y1 = as_matrix(Y1, "history outputs Y1", cols=ss.n_outputs, min_rows=1)
        U1 = np.zeros((len(Y1), ss.n_inputs)) if U1 is None else \
            as_matrix(U1, "history inputs U1", cols=ss.n_inputs)
        rho = ss.spectral_radius()
        W = max(100, 20 * -(-ss.n_states // ss.n_outputs), min(10_000, int(np.ceil(1 / (1 - rho)))))
        W = min(W, len(Y1))
        return estimate_state(ss, Y1[-W:], U1[-W:], None, rcond=self.seed_rcond)

    def simulate(self, U: np.ndarray, history: Any = None, x0: np.ndarray | None = None) -> np.ndarray:
        """Free-run prediction (len(U), p) driven by U (K, m), seeded from ``history`` or ``x0``."""
        return self.model_.simulate(U, self.initial_state(history) if x0 is None else x0)


class ParametricROM(BaseEstimator):
    """Models fitted at parameter samples, matched mode by mode, interpolated in pole-residue form.

    Args:
        base_estimator: any method of :mod:`node.sysid` (WDMD, DelayDMD, ...); a copy is
            fitted per sample (``sklearn.base.clone`` when it has ``get_params``, else a deep copy).
        n_pairs: dominant complex-conjugate pole pairs kept, ranked by their mean share over the
            samples of the modes' peak gains ||R||_F / (1 - |z|) (the H2 norm ||R||^2 / (1 - |z|^2)
            ranks broadband modes fitted to noise above lightly damped physical ones).
        n_real: dominant real poles (0 < z < 1) kept besides.
        scheme: what is interpolated, in the ZOH-equivalent s-plane. ``"modal"`` (default):
            w^2 = |s|^2, 2 zeta w = -2 Re s and R_s w; ``"direct"``: the poles s and residues
            R_s themselves, the text's eq. 6.10. Modal is the default because a stiffness-like
            parameter moves w^2 linearly while w, the pole and the residue (~ 1 / w) follow its
            square root. On the axially loaded beam (``python -m bench parametric``, models at
            p = 0, 3, 4, Lagrange weights) eps_td at p = 2 is 5.9e-3 against 1.6e-1 for eq. 6.10.
        weights: ``"lagrange"`` (polynomial through the samples, one parameter), ``"linear"``
            (piecewise linear, one parameter, linear beyond the ends), ``"rbf"`` (thin-plate
            spline with a linear term over range-scaled parameters, any number of them);
            ``"auto"``: Lagrange for one parameter, RBF for several. ``"regress"``: the
            least-squares line (plane) through the samples evaluated at p, w = [1, x] pinv([1, P]):
            weights that sum to 1 and smooth run-to-run scatter of identified models instead of
            interpolating it (any number of parameters); ``"mean"``: equal weights (the
            parameter ignored: the control that tells what the parameter adds).
        mac_weight: weight of 1 - MAC(output directions) MAC(input directions) beside the
            relative pole distance |s_a - s_b| / max(|s_a|, |s_b|) in the matching cost.
        tol: largest matching cost accepted; a kept mode whose match costs more at some sample
            is left out of the model and listed in ``unmatched_`` (with a logged warning).
        static: keep the static gain: ``at`` sets D so that the model's static gain is the
            weighted sum of the samples' full static gains (modal truncation with static
            correction). Identified quasi-static models carry most of their gain in D and a slow
            real pole near z = 1 (R / (1 - z)): the kept modes alone lose it, and interpolating
            R and z apart scrambles it (engine OCs, ``bench prom-engine``: eps_td 1.37 -> 0.06).
        clip: keep to the library's range: the parameter is clipped to the samples' range per
            parameter, each interpolated pole's Re s and Im s to the range of its mode over the
            samples. Weights with negative entries (Lagrange, regress, RBF) otherwise move a slow
            real pole onto z = 1 and extrapolate a plane beyond the samples' hull (engine OCs:
            held-out eps_td 1e6-1e8 without).
        verbose: a mode left out is a logged warning (False: a debug message, for callers
            that try many settings and read ``unmatched_`` themselves).

    Learned attributes: ``estimators_`` (the fitted copies), ``params_`` (n, q), ``poles_``
    (n, r) complex discrete-time poles of the matched modes (the pairs by their upper-half-plane
    pole, then the real poles), ``residues_`` (n, r, p, m) discrete residues, ``D_`` (n, p, m),
    ``dt_`` (s), ``unmatched_`` (list of (sample index, pole at its parent sample, cost)),
    ``dc_`` (n, p, m) the samples' full static gains. ``to_arrays`` / ``from_arrays`` store and
    restore what ``at`` needs (no estimators, no pickle).

    Three oscillators seen through different mode shapes; the first one's stiffness grows
    with p so that its frequency passes the second's (the matching follows the mode shapes):

    >>> from node.sysid import DelayDMD
    >>> def system(p, dt=0.01):
    ...     f = np.array([2.0 * np.sqrt(1 + 1.5 * p), 3.0, 4.5])          # Hz
    ...     lam = -0.02 * 2 * np.pi * f + 2j * np.pi * f * np.sqrt(1 - 0.02 ** 2)
    ...     z = np.exp(lam * dt)
    ...     shapes = np.array([[1.0, 0.2, 0.1], [0.1, 1.0, -0.3], [0.3, -0.2, 1.0]])
    ...     R = shapes.T[:, :, None] * (1e-3 / (z - 1))[:, None, None]
    ...     return PoleResidue(np.r_[z, z.conj()], np.r_[R, R.conj()], np.zeros((3, 1)),
    ...                        dt).to_statespace()
    >>> u = np.random.default_rng(0).normal(size=(3000, 1))
    >>> ps = [0.0, 0.5, 1.0, 1.5]
    >>> rom = ParametricROM(DelayDMD(delays=2, input_delays=2, dt=0.01), n_pairs=3).fit(
    ...     [(system(p).simulate(u), u) for p in ps], ps)
    >>> f = np.angle(rom.poles_) / (2 * np.pi * 0.01)
    >>> np.round(f[:, np.argmin(f[0])], 2)    # the stiffened mode, tracked through the crossing
    array([2.  , 2.65, 3.16, 3.6 ])
    >>> m = rom.at(0.75)
    >>> m.model_.is_stable(), np.allclose(m.simulate(u[:500]), system(0.75).simulate(u[:500]),
    ...                                   atol=1e-3 * np.abs(system(0.75).simulate(u)).max())
    (True, True)
    """

    def __init__(self, base_estimator: Any, n_pairs: int = 4, n_real: int = 0, scheme: str = "modal",
                 weights: str = "auto", mac_weight: float = 1.0, tol: float = 0.5,
                 static: bool = False, clip: bool = False, verbose: bool = True) -> None:
        self.base_estimator = base_estimator
        self.n_pairs = n_pairs
        self.n_real = n_real
        self.scheme = scheme
        self.weights = weights
        self.mac_weight = mac_weight
        self.tol = tol
        self.static = static
        self.clip = clip
        self.verbose = verbose

    # --- fit ------------------------------------------------------------------------------
    def _check_params(self) -> None:
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {SCHEMES}, got {self.scheme!r}")
        if self.weights not in WEIGHTS:
            raise ValueError(f"weights must be one of {WEIGHTS}, got {self.weights!r}")
        for name in ("n_pairs", "n_real"):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {v!r}")
        if self.n_pairs + self.n_real < 1:
            raise ValueError("keep at least one mode (n_pairs + n_real >= 1)")

    def _copy(self) -> Any:
        if hasattr(self.base_estimator, "get_params"):
            from sklearn.base import clone
            return clone(self.base_estimator)
        return copy.deepcopy(self.base_estimator)

    def fit(self, samples: Any, params: Any) -> ParametricROM:
        """Fit a model per sample: ``samples`` a list (one per sample) of (Y, U) pairs or lists of
        pairs (Y (K, p), U (K, m)); ``params`` (n,) or (n, q). Returns self."""
        samples = list(samples)
        P = self._check_samples(params, len(samples))
        self.estimators_ = []
        for sample in samples:
            Ys, Us = _as_pairs(sample)
            est = self._copy().fit(Ys if len(Ys) > 1 else Ys[0], Us if len(Us) > 1 else Us[0])
            self.estimators_.append(est)
        return self.fit_models([_model_of(est) for est in self.estimators_], P)

    def _check_samples(self, params: Any, n: int) -> np.ndarray:
        self._check_params()
        P = np.asarray(params, dtype=float)
        P = P[:, None] if P.ndim == 1 else P
        if P.ndim != 2 or len(P) != n or len(P) < 2:
            raise ValueError(f"need params (n,) or (n, q) for n >= 2 samples; got {P.shape} for "
                             f"{n} samples")
        if self.weights in ("lagrange", "linear") and P.shape[1] > 1:
            raise ValueError(f"weights={self.weights!r} takes one parameter; use 'rbf' for {P.shape[1]}")
        return P

    def fit_models(self, models: Any, params: Any) -> ParametricROM:
        """Build from models identified beforehand (a list of :class:`StateSpace`, one per
        sample) instead of fitting the base estimator: ``fit`` without its first step. Returns self."""
        models = list(models)
        P = self._check_samples(params, len(models))
        if not hasattr(self, "estimators_") or len(self.estimators_) != len(models):
            self.estimators_ = []
        forms = [_modal_form(ss) for ss in models]
        prs = [f[0] for f in forms]
        self.dc_ = np.stack([f[1] for f in forms])
        self.params_ = P
        self.dt_ = float(prs[0].dt)
        self._scale = np.where(np.ptp(P, axis=0) > 0, np.ptp(P, axis=0), 1.0)
        # 1-D: a chain in parameter order; else each sample matched to its nearest matched one
        order = np.argsort(P[:, 0], kind="stable") if P.shape[1] == 1 else np.arange(len(P))
        edges = [(int(order[i]), int(order[i - 1])) for i in range(1, len(P))] if P.shape[1] == 1 \
            else _tree(P / self._scale)
        root = int(order[0])
        self.unmatched_: list[tuple[int, complex, float]] = []
        s_all, R_all = [], []
        for real, keep in ((False, int(self.n_pairs)), (True, int(self.n_real))):
            if keep:
                s, R = self._match([_modes(pr, real) for pr in prs], root, edges, keep)
                s_all.append(s)
                R_all.append(R)
        if sum(s.shape[1] for s in s_all) == 0:
            raise ValueError("no mode could be matched across the samples (see unmatched_)")
        self._n_pairs_kept = s_all[0].shape[1] if self.n_pairs else 0
        self._s = np.hstack(s_all)  # (n, r) continuous poles
        self._R = np.concatenate(R_all, axis=1)  # (n, r, p, m) continuous residues
        self.D_ = np.stack([pr.D.real for pr in prs])
        z = np.exp(self._s * self.dt_)
        self.residues_ = self._R * ((z - 1.0) / self._s)[:, :, None, None]
        self.poles_ = z
        return self

    def _match(self, modes: list[_Modes], root: int, edges: list[tuple[int, int]],
               keep: int) -> tuple[np.ndarray, np.ndarray]:
        """Tracks from every mode of the root sample, linked along ``edges`` by assignment;
        the ``keep`` with the largest mean peak share; those with a link above tol are reported.
        Returns s (n, r) and R_s (n, r, p, m) of the matched tracks."""
        n = len(modes)
        track = np.full((n, len(modes[root].s)), -1)
        track[root] = np.arange(len(modes[root].s))
        broke: dict[int, tuple[int, float]] = {}  # track -> (sample, cost) of its first bad link
        for child, parent in edges:
            rows = np.where(track[parent] >= 0)[0]
            idx = track[parent, rows]
            pm = _Modes(modes[parent].s[idx], modes[parent].R[idx], modes[parent].share[idx])
            cost = _cost(pm, modes[child], self.mac_weight)
            r, c = linear_sum_assignment(cost)
            track[child, rows[r]] = c
            for j in np.setdiff1d(rows, rows[r]):
                broke.setdefault(int(j), (child, float("inf")))
            for j, cj in zip(rows[r], cost[r, c]):
                if cj > self.tol:
                    broke.setdefault(int(j), (child, float(cj)))
        share = np.array([[modes[i].share[t] if t >= 0 else 0.0 for t in track[i]] for i in range(n)])
        ranked = [int(j) for j in np.argsort(-share.mean(axis=0), kind="stable")[:keep]]
        for j in ranked:
            if j in broke:
                pole = complex(np.exp(modes[root].s[j] * self.dt_))
                self.unmatched_.append((broke[j][0], pole, broke[j][1]))
                log.log(logging.WARNING if self.verbose else logging.DEBUG,
                        "the mode at z = %.5g%+.5gj of sample %d has no match within tol %.3g at "
                        "sample %d (cost %.3g): left out", pole.real, pole.imag, root, self.tol, *broke[j])
        good = [j for j in ranked if j not in broke]
        p, m = modes[root].R.shape[1:]
        s = np.array([[modes[i].s[track[i, j]] for j in good] for i in range(n)], dtype=complex)
        R = np.array([[modes[i].R[track[i, j]] for j in good] for i in range(n)], dtype=complex)
        return s.reshape(n, len(good)), R.reshape(n, len(good), p, m)

    # --- interpolate --------------------------------------------------------------------------
    def _require_fit(self) -> None:
        if not hasattr(self, "poles_"):
            from sklearn.exceptions import NotFittedError
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet: call fit first")

    def weights_at(self, p: Any) -> np.ndarray:
        """Interpolation weights (n,) of the samples at parameter value ``p`` (scalar or (q,))."""
        self._require_fit()
        P = self.params_
        x = np.asarray(p, dtype=float).reshape(-1)
        if x.size != P.shape[1]:
            raise ValueError(f"the model has {P.shape[1]} parameter(s), got {x.size} value(s)")
        if self.clip:
            x = np.clip(x, P.min(axis=0), P.max(axis=0))
        kind = self.weights if self.weights != "auto" else ("lagrange" if P.shape[1] == 1 else "rbf")
        n = len(P)
        if kind == "mean":
            return np.full(n, 1.0 / n)
        if kind == "regress":
            X = np.column_stack([np.ones(n), P / self._scale])
            return np.asarray(np.r_[1.0, x / self._scale] @ np.linalg.pinv(X))
        if kind == "rbf":
            from scipy.interpolate import RBFInterpolator
            rbf = RBFInterpolator(P / self._scale, np.eye(n), kernel="thin_plate_spline", degree=1)
            return np.asarray(rbf((x / self._scale)[None, :])[0])
        t = P[:, 0]
        if kind == "lagrange":
            w = np.ones(n)
            for i in range(n):
                for j in range(n):
                    if j != i:
                        w[i] *= (x[0] - t[j]) / (t[i] - t[j])
            return w
        order = np.argsort(t)
        k = int(np.clip(np.searchsorted(t[order], x[0]) - 1, 0, n - 2))
        lo, hi = order[k], order[k + 1]
        a = (x[0] - t[lo]) / (t[hi] - t[lo])
        w = np.zeros(n)
        w[lo], w[hi] = 1.0 - a, a
        return w

    def _interpolate(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous poles (r,) and residues (r, p, m) for sample weights w (n,), Re s < 0."""
        s, R = self._s, self._R
        k = self._n_pairs_kept
        tiny = 1e-9 / self.dt_
        if self.scheme == "modal":
            w0 = np.abs(s)
            w2 = np.maximum(w @ w0 ** 2, tiny ** 2)
            c = np.maximum(w @ (-2.0 * s.real), 2 * tiny)  # 2 zeta w
            # a pair whose interpolated damping would make it overdamped stays a critically damped pair
            wd = np.sqrt(np.maximum(w2 - c ** 2 / 4, tiny ** 2))
            si = np.where(np.arange(s.shape[1]) < k, -c / 2 + 1j * wd, -c / 2 + 0j)
            Ri = np.einsum("i,ijpm->jpm", w, R * w0[:, :, None, None]) / np.sqrt(w2)[:, None, None]
        else:
            si = w @ s
            si = np.minimum(si.real, -tiny) + 1j * np.where(np.arange(s.shape[1]) < k, si.imag, 0.0)
            Ri = np.einsum("i,ijpm->jpm", w, R)
        if self.clip:
            si = np.clip(si.real, s.real.min(axis=0), s.real.max(axis=0)) + \
                1j * np.clip(si.imag, s.imag.min(axis=0), s.imag.max(axis=0))
        return si, Ri

    def _statespace(self, s: np.ndarray, R: np.ndarray, D: np.ndarray) -> StateSpace:
        z = np.exp(s * self.dt_)
        Rz = R * ((z - 1.0) / s)[:, None, None]
        k = self._n_pairs_kept
        poles = np.r_[z[:k], z[:k].conj(), z[k:].real + 0j]
        res = np.concatenate([Rz[:k], Rz[:k].conj(), Rz[k:].real + 0j])
        return PoleResidue(poles, res, D.astype(complex), self.dt_).to_statespace()

    def at(self, p: Any) -> ParametricModel:
        """The model at parameter value ``p`` (scalar or (q,)): real, stable, discrete-time."""
        return self.at_weights(self.weights_at(p))

    def at_weights(self, w: np.ndarray) -> ParametricModel:
        """The model for sample weights w (n,) (``weights_at`` gives them for a parameter value)."""
        self._require_fit()
        s, R = self._interpolate(np.asarray(w, float))
        D = np.einsum("i,ipm->pm", w, self.D_)
        if self.static:
            D = np.einsum("i,ipm->pm", w, self.dc_) - static_gain(self._statespace(s, R, np.zeros_like(D)))
        return ParametricModel(self._statespace(s, R, D))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """What ``at`` needs, as real arrays (``from_arrays`` restores it): no estimators."""
        self._require_fit()
        return {"rom_format": np.array([FORMAT]), "rom_s_re": self._s.real, "rom_s_im": self._s.imag,
                "rom_R_re": self._R.real, "rom_R_im": self._R.imag, "rom_D": self.D_, "rom_dc": self.dc_,
                "rom_params": self.params_, "rom_scale": self._scale,
                "rom_meta": np.array([self.dt_, float(self._n_pairs_kept)])}

    @classmethod
    def from_arrays(cls, arrays: Any, **params: Any) -> ParametricROM:
        """A fitted ROM from ``to_arrays``' output and the constructor's parameters (no base
        estimator: it cannot be refitted, only evaluated)."""
        if int(np.asarray(arrays["rom_format"])[0]) != FORMAT:
            raise ValueError(f"parametric model arrays of format {int(arrays['rom_format'][0])}; "
                             f"this version reads {FORMAT}")
        rom = cls(None, **params)
        rom._s = np.asarray(arrays["rom_s_re"]) + 1j * np.asarray(arrays["rom_s_im"])
        rom._R = np.asarray(arrays["rom_R_re"]) + 1j * np.asarray(arrays["rom_R_im"])
        rom.D_ = np.asarray(arrays["rom_D"], float)
        rom.dc_ = np.asarray(arrays["rom_dc"], float)
        rom.params_ = np.asarray(arrays["rom_params"], float)
        rom._scale = np.asarray(arrays["rom_scale"], float)
        rom.dt_ = float(arrays["rom_meta"][0])
        rom._n_pairs_kept = int(arrays["rom_meta"][1])
        rom.unmatched_ = []
        z = np.exp(rom._s * rom.dt_)
        rom.residues_ = rom._R * ((z - 1.0) / rom._s)[:, :, None, None]
        rom.poles_ = z
        return rom

    def library_model(self, i: int) -> StateSpace:
        """The matched modes of sample ``i`` alone, as a state space (what ``at`` reproduces there)."""
        self._require_fit()
        return self._statespace(self._s[i], self._R[i], self.D_[i])
