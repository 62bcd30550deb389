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

Where two modes veer or cross (their frequencies come close, their shapes rotate into each
other), one-to-one matching has no right answer: such a group is interpolated as a block,
its upper-half-plane realisation (A', B', C') put in a basis common to all samples (the one
in which C' is the same, up to a least-squares projection); there A'^2 (for a stiffness-like
parameter minus the stiffness matrix in that basis, nearly linear in the parameter), A' B' (the
force distribution) and C' are fitted as one model of the parameter to all samples' frequency
responses at once (:mod:`node.sysid.joint_block`: interpolating each sample's block passes
through its identification errors, which the veering amplifies), or interpolated sample by
sample (``block="interpolate"``); the group's modes at ``p`` are the block's eigenvectors.
"""

from __future__ import annotations

import copy
import logging
import warnings
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
from scipy import sparse
from scipy.linalg import subspace_angles
from scipy.optimize import linear_sum_assignment
from sklearn.base import BaseEstimator

from node.sysid.joint_block import JointBlock, fit_joint
from node.sysid.joint_block import modes as joint_modes
from node.sysid.memo import ContentMemo
from node.sysid.metrics import mac
from node.sysid.observer import estimate_state
from node.sysid.prom_loo import MARGIN as LOO_MARGIN
from node.sysid.prom_loo import Candidate, Data, Validation
from node.sysid.prom_loo import nearest as nearest_sample
from node.sysid.prom_loo import validate as loo_validate
from node.sysid.prom_residues import fit as fit_residues
from node.sysid.statespace import PoleResidue, StateSpace
from node.sysid.validation import as_matrix

log = logging.getLogger(__name__)

SCHEMES = ("modal", "inverse", "direct", "auto")
WEIGHTS = ("auto", "lagrange", "linear", "rbf", "regress", "mean")
# version of ``to_arrays`` (1: no groups nor fallback modes; 2: groups interpolated per sample; still read)
FORMAT = 3
FALLBACKS = ("nearest", "drop")
BLOCKS = ("joint", "interpolate", "none", "auto")
MATCHES = ("continuation", "assignment", "auto")
VALIDATES = ("loo", "none")
RESIDUES = ("data", "model")
# continuation's matching cost of a factor e between two modes' peak shares: a mode's peak gain
# changes slowly along the parameter, a jump by 100 (a physical mode to a noise mode) costs 0.46
SHARE_WEIGHT = 0.1
ROTATION = 0.02  # 1 - MAC_out MAC_in along a track above which close tracks are a veering group


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
# a sample's kept modes' residues fitted to its data, per pole set: the folds and candidates of a
# leave-one-sample-out validation refit the same samples with the same modes
_RESIDUES: ContentMemo[tuple[np.ndarray, np.ndarray] | None] = ContentMemo(512)


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


def _cost(a: _Modes, b: _Modes, mac_weight: float, pred: np.ndarray | None = None,
          gain_weight: float = 0.0) -> np.ndarray:
    """(k_a, k_b): relative s-plane distance + mac_weight (1 - MAC_out MAC_in) + gain_weight
    |ln(share_a / share_b)|. With ``pred`` (k_a,) the poles of a predicted by continuation, the
    distance is the smaller of the two."""
    def dist(sa: np.ndarray) -> np.ndarray:
        return np.abs(sa[:, None] - b.s[None, :]) / np.maximum(np.abs(sa)[:, None], np.abs(b.s)[None, :])
    d = dist(a.s) if pred is None else np.minimum(dist(a.s), dist(pred))
    ua, va = _directions(a.R)
    ub, vb = _directions(b.R)
    gain = np.abs(np.log(np.maximum(a.share, 1e-12)[:, None] / np.maximum(b.share, 1e-12)[None, :]))
    return d + mac_weight * (1.0 - mac(ua, ub) * mac(va, vb)) + gain_weight * gain


def _predict(s_par: np.ndarray, s_gp: np.ndarray, t: float) -> np.ndarray:
    """Continuation: poles at parameter parent + t (parent - grandparent), w^2 and 2 zeta w
    extrapolated linearly (the modal scheme's coordinates)."""
    w2 = np.abs(s_par) ** 2 + t * (np.abs(s_par) ** 2 - np.abs(s_gp) ** 2)
    c = -2 * s_par.real + t * (-2 * s_par.real + 2 * s_gp.real)
    return -c / 2 + 1j * np.sqrt(np.maximum(w2 - c ** 2 / 4, 0.0))


def _rank1(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Columns c (p, g) and rows b (g, m) with R_j ~ outer(c_j, b_j): each residue's leading SVD term."""
    u, sv, vh = np.linalg.svd(R)
    return (u[:, :, 0] * sv[:, :1]).T, vh[:, 0, :]


def _span_similarity(X: np.ndarray, Y: np.ndarray) -> float:
    """prod cos^2 of the principal angles between the column spans of X and Y (p, g); 1 if p <= g."""
    if X.shape[0] <= X.shape[1]:
        return 1.0
    return float(np.prod(np.cos(subspace_angles(X, Y)) ** 2))


def _set_cost(a: _Modes, b: _Modes, mac_weight: float) -> float:
    """Cost of matching two sets of modes as sets (a veering group): mean relative distance of
    their poles in frequency order + mac_weight (1 - similarity of the spans of their output
    and of their input directions)."""
    sa, sb = a.s[np.argsort(np.abs(a.s))], b.s[np.argsort(np.abs(b.s))]
    dist = float(np.mean(np.abs(sa - sb) / np.maximum(np.abs(sa), np.abs(sb))))
    ca, ba = _rank1(a.R)
    cb, bb = _rank1(b.R)
    return dist + mac_weight * (1.0 - _span_similarity(ca, cb) * _span_similarity(ba.T, bb.T))


@dataclass(frozen=True)
class _Block:
    """A veering group's realisations in a common basis, one per sample: X (n, g, g) (A'^2 for
    the modal scheme, A' for direct), Y (n, g, m) (A' B' or B'), C (n, p, g) (C'), and the
    coefficients of det(x I - X), smooth through a veering or a crossing (the sorted
    eigenvalues have a kink at a crossing) and set by the poles alone (shapes identified from
    noisy data scatter far more than poles, most for a weakly excited mode)."""

    X: np.ndarray
    Y: np.ndarray
    C: np.ndarray
    poly: np.ndarray  # (n, g + 1) characteristic polynomial of X: its eigenvalues' symmetric functions


@dataclass(frozen=True)
class _Matched:
    """``_match``'s result: s (n, r), R (n, r, p, m) of the matched tracks; groups (column lists)
    and their blocks; fallback modes fs (n, f), fR (n, f, p, m), NaN where not the mode."""

    s: np.ndarray
    R: np.ndarray
    groups: list[list[int]]
    blocks: list[_Block]
    fs: np.ndarray
    fR: np.ndarray


def _common_basis(s: np.ndarray, R: np.ndarray, modal: bool, max_cond: float = 1e4) -> _Block | None:
    """The upper-half-plane realisation (A' = T^-1 diag(s) T, B' = T^-1 B, C' = C T) of each
    sample's group, s (n, g), R (n, g, p, m), in the basis where C' is the least-squares nearest
    to one C_ref (p >= g; the leading g left singular vectors of all samples' unit output
    directions), else where B' is nearest to one B_ref (m >= g). None when neither side has g
    independent directions at every sample (cond > ``max_cond``): no common basis."""
    n, g = s.shape
    p, m = R.shape[2:]
    CB = [_rank1(R[i]) for i in range(n)]
    if p < g and m < g:
        return None
    out = p >= g
    # the aligned side of each sample: output columns (p, g), or input rows transposed (m, g)
    sides = [c if out else b.T for c, b in CB]
    units = [x / np.linalg.norm(x, axis=0) for x in sides]
    if any(np.linalg.cond(x) > max_cond for x in units):
        return None
    ref = np.linalg.svd(np.hstack(units))[0][:, :g]
    X, Y, C = [], [], []
    for i in range(n):
        c, b = CB[i]
        T = np.linalg.pinv(c) @ ref if out else np.linalg.inv(ref.T @ np.linalg.pinv(b))
        Ti = np.linalg.inv(T)
        A1 = Ti @ np.diag(s[i]) @ T
        B1 = Ti @ b
        X.append(A1 @ A1 if modal else A1)
        Y.append(A1 @ B1 if modal else B1)
        C.append(c @ T)
    poly = np.array([np.poly(s[i] ** 2 if modal else s[i]) for i in range(n)])
    return _Block(np.array(X), np.array(Y), np.array(C), poly)


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


def _range_scale(P: np.ndarray) -> np.ndarray:
    """Each parameter's range over the samples (q,) (1 where it does not vary)."""
    return np.where(np.ptp(P, axis=0) > 0, np.ptp(P, axis=0), 1.0)


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


def _as_sample_list(samples: Any) -> list[Any]:
    """``fit``'s samples as a list, one entry per parameter sample. One array (scikit-learn's X)
    is refused: sparse, complex, non-finite or empty arrays with the usual one-line messages
    (``as_matrix``), any other with what ``fit`` takes instead."""
    if isinstance(samples, (list, tuple)):
        return list(samples)
    if sparse.issparse(samples) or isinstance(samples, np.ndarray) or hasattr(samples, "__array__"):
        arr = as_matrix(samples, "samples", min_rows=1, min_cols=1, allow_1d=False)
        raise ValueError(f"samples is one array of shape {arr.shape} (scikit-learn's X: {arr.shape[0]} "
                         f"sample(s) of {arr.shape[1]} feature(s)): ParametricROM.fit takes a list with "
                         f"one (Y, U) pair (or list of pairs) per parameter sample, and params")
    return list(samples)


class ParametricFallbackWarning(UserWarning):
    """A :class:`ParametricROM` that uses a sample's model as it is instead of interpolating: the
    whole model (no setting beats the nearest sample's model by leave-one-sample-out) or some
    modes (no match across the samples)."""


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
        n_pairs: dominant complex-conjugate pole pairs kept (at most: ``validate`` may keep
            fewer), ranked by their mean share over the
            samples of the modes' peak gains ||R||_F / (1 - |z|) (the H2 norm ||R||^2 / (1 - |z|^2)
            ranks broadband modes fitted to noise above lightly damped physical ones).
        n_real: dominant real poles (0 < z < 1) kept besides.
        scheme: what is interpolated, in the ZOH-equivalent s-plane. ``"modal"``: w^2 = |s|^2,
            2 zeta w = -2 Re s and R_s w; ``"inverse"``: 1 / w^2, 2 zeta w / w^2 and R_s / w;
            ``"direct"``: the poles s and residues R_s themselves, the text's eq. 6.10;
            ``"auto"`` (default): modal or inverse, chosen by ``validate`` (modal without it).
            A stiffness-like parameter moves w^2 linearly while w, the pole and the residue
            (~ 1 / w) follow its square root; a mass-like one moves 1 / w^2 linearly (and with
            Rayleigh damping 2 zeta w / w^2; R_s / w stays). On the axially loaded beam
            (``python -m bench parametric``, models at p = 0, 3, 4, Lagrange weights) eps_td at
            p = 2 is 5.9e-3 for modal against 1.6e-1 for eq. 6.10. Veering groups' blocks are in
            modal variables unless ``"direct"``.
        weights: ``"lagrange"`` (polynomial through the samples, one parameter), ``"linear"``
            (piecewise linear, one parameter, linear beyond the ends), ``"rbf"`` (thin-plate
            spline with a linear term over range-scaled parameters, any number of them);
            ``"auto"`` (default): chosen by ``validate`` among Lagrange and linear for one
            parameter, RBF and regress for several (without it: Lagrange, RBF). ``"regress"``: the
            least-squares line (plane) through the samples evaluated at p, w = [1, x] pinv([1, P]):
            weights that sum to 1 and smooth run-to-run scatter of identified models instead of
            interpolating it (any number of parameters); ``"mean"``: equal weights (the
            parameter ignored: the control that tells what the parameter adds).
        mac_weight: weight of 1 - MAC(output directions) MAC(input directions) beside the
            relative pole distance |s_a - s_b| / max(|s_a|, |s_b|) in the matching cost.
        tol: largest matching cost accepted; a kept mode whose match costs more at some sample
            (a veering group: whose match as a set does) is listed in ``unmatched_`` (with a
            logged warning) and not interpolated (see ``fallback``).
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
        match: ``"continuation"``: each sample's modes assigned to the tracks on the
            cost to the parent sample's mode or to its continuation (w^2 and 2 zeta w extrapolated
            from the two samples before), plus 0.1 |ln| of the ratio of their peak shares (a
            physical mode does not turn into a weak noise mode); kept complex tracks that cross
            or come within ``veer_gap`` of each other while a shape turns (1 - MAC > 0.02), or
            that both turn at a link where as a set they cost less than apart, form a veering
            group, matched as a set (poles in frequency order, span of the directions) and
            modelled as a block (module docstring; see ``block``). Needs as many outputs (or
            inputs) as modes in the group, else the group is unmatched. ``"assignment"``:
            one-to-one on pole distance and MAC alone, no groups (the matcher before veering
            groups). ``"auto"`` (default): chosen by ``validate`` (continuation without it).
        veer_gap: relative frequency gap |w_a - w_b| / max below which two tracks whose shapes
            turn are a veering group (0: only crossings).
        fallback: ``"nearest"`` (default): an unmatched mode enters the model at ``p`` as it is
            in the sample of largest weight (the nearest, for Lagrange or linear weights), when
            it was matched up to that sample; ``"drop"``: it is left out.
        block: how a veering group's block (A'^2, A' B', C' in a basis common to the samples)
            varies with the parameter. ``"joint"``: one model, A'^2 quadratic in the
            parameter(s) (the monomials the samples determine), A' B' and C' fixed (in these modal
            variables whatever the scheme), fitted by least squares to all samples' frequency
            responses of the group at once (:mod:`node.sysid.joint_block`); its poles and shapes
            are the eigenvalues and eigenvectors at p. On the near-crossing of ``harness.veering``
            (modes 3 % apart, 2 % damping) eps_td at the crossing is 1.35 times the model fitted
            there (4.1 with ``"interpolate"``). ``"interpolate"``: each sample's block
            interpolated with the weights, the poles from the interpolated characteristic
            polynomial (passes through every sample's group exactly, and through its
            identification errors). ``"none"``: no groups (every track one-to-one).
            ``"auto"`` (default): chosen by ``validate`` (joint without it).
        validate: ``"loo"`` (default): ``fit`` chooses the settings left ``"auto"`` (``match``,
            ``block``, ``weights``, ``scheme``) and how many of the ``n_pairs`` pairs to keep (1 to
            ``n_pairs``) by leave-one-sample-out on its data (:mod:`node.sysid.prom_loo`): when
            some sample is interior (inside the others' range, or hull for several parameters),
            each sample is rebuilt from the others' models (interpolated to an interior one,
            extrapolated to one at the edge, which weighs 0.3) and its free run from rest under
            that sample's inputs scored against that sample's outputs (eps_td capped at 1,
            ``prom_loo.score``); the lowest weighted mean score
            wins (within 2 %: the earlier candidate, the settings without validation first). When
            it does not beat the nearest other sample's model, scored the same way, ``at``
            returns the nearest sample's fitted model (``fallback_``) with one
            :class:`ParametricFallbackWarning`.
            Without an interior sample (two samples, or none inside the others' hull),
            ``fit_models`` (models, no data) or ``"none"``: the settings as given, ``"auto"``
            as noted and all ``n_pairs``. Either way ``validation_`` says how it decided. A
            setting is used only when its mean score is below 0.85 times the nearest sample's
            (``prom_loo.MARGIN``: the folds are coarser than the final model).
        residues: ``"data"`` (default): each sample's kept modes' residues (and D) are fitted to
            that sample's data by output-error least squares, its poles kept
            (:mod:`node.sysid.prom_residues`: unbiased by output noise, and they take up what the
            modes left out explained); ``fit_models`` (no data) copies them. ``"model"``: copied
            from each sample's identified model.

    Learned attributes: ``estimators_`` (the fitted copies), ``params_`` (n, q), ``poles_``
    (n, r) complex discrete-time poles of the matched modes (the pairs by their upper-half-plane
    pole, then the real poles), ``residues_`` (n, r, p, m) discrete residues, ``D_`` (n, p, m),
    ``dt_`` (s), ``unmatched_`` (list of (sample index, pole at the root sample, cost) of the
    first bad link; the root and inf when its group has no common basis),
    ``dc_`` (n, p, m) the samples' full static gains, ``groups_`` (lists of columns of
    ``poles_``: the veering groups, modelled as blocks), ``choice_`` (the
    :class:`~node.sysid.prom_loo.Candidate` used: match, block, n_pairs, weights),
    ``validation_`` (:class:`~node.sysid.prom_loo.Validation`: the rule and the scores, also in
    ``repr``), ``fallback_`` (True: ``at`` returns the nearest sample's model). ``to_arrays`` /
    ``from_arrays`` store and restore what ``at`` needs (no estimators, no pickle).

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

    choice_: Candidate  # set by fit / fit_models / from_arrays

    def __init__(self, base_estimator: Any, n_pairs: int = 4, n_real: int = 0, scheme: str = "auto",
                 weights: str = "auto", mac_weight: float = 1.0, tol: float = 0.5,
                 static: bool = False, clip: bool = False, verbose: bool = True,
                 match: str = "auto", veer_gap: float = 0.1, fallback: str = "nearest",
                 block: str = "auto", validate: str = "loo", residues: str = "data") -> None:
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
        self.match = match
        self.veer_gap = veer_gap
        self.fallback = fallback
        self.block = block
        self.validate = validate
        self.residues = residues

    def __repr__(self, N_CHAR_MAX: int = 700) -> str:
        """scikit-learn's repr; once fitted, followed by how the settings were decided."""
        text = super().__repr__(N_CHAR_MAX)
        val = getattr(self, "validation_", None)
        return text if val is None else f"{text}  # {val.summary()}"

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
        if self.match not in MATCHES:
            raise ValueError(f"match must be one of {MATCHES}, got {self.match!r}")
        if self.fallback not in FALLBACKS:
            raise ValueError(f"fallback must be one of {FALLBACKS}, got {self.fallback!r}")
        if self.block not in BLOCKS:
            raise ValueError(f"block must be one of {BLOCKS}, got {self.block!r}")
        if self.residues not in RESIDUES:
            raise ValueError(f"residues must be one of {RESIDUES}, got {self.residues!r}")
        if self.validate not in VALIDATES:
            raise ValueError(f"validate must be one of {VALIDATES}, got {self.validate!r}")
        if not 0 <= float(self.veer_gap) < 1:
            raise ValueError(f"veer_gap must be in [0, 1), got {self.veer_gap!r}")
        if self.n_pairs + self.n_real < 1:
            raise ValueError("keep at least one mode (n_pairs + n_real >= 1)")

    def _copy(self) -> Any:
        if hasattr(self.base_estimator, "get_params"):
            from sklearn.base import clone
            return clone(self.base_estimator)
        return copy.deepcopy(self.base_estimator)

    def fit(self, samples: Any, params: Any) -> ParametricROM:
        """Fit a model per sample: ``samples`` a list (one per sample) of (Y, U) pairs or lists of
        pairs (Y (K, p), U (K, m)); ``params`` (n,) or (n, q). With ``validate="loo"`` the
        settings are chosen on these data (see ``validate``). Returns self."""
        samples = _as_sample_list(samples)
        P = self._check_samples(params, len(samples))
        self.estimators_ = []
        data = []
        for sample in samples:
            Ys, Us = _as_pairs(sample)
            est = self._copy().fit(Ys if len(Ys) > 1 else Ys[0], Us if len(Us) > 1 else Us[0])
            self.estimators_.append(est)
            data.append(list(zip(Ys, Us)))
        models = [_model_of(est) for est in self.estimators_]
        if self.validate == "none":
            return self._build(models, P, self._default_choice(P.shape[1]), Validation("off", None),
                               data=data)
        scale = _range_scale(P)

        def fold(cand: Candidate, rest: list[int]) -> ParametricROM:
            return self._fold(cand, [models[j] for j in rest], P[rest], [data[j] for j in rest])

        val = loo_validate(models, P, scale, data, self._candidates(P.shape[1]), fold)
        if not val.held_out:
            return self._build(models, P, self._default_choice(P.shape[1]),
                               Validation("no interior sample", None), data=data)
        best = val.best()
        assert best is not None
        means = val.mean_scores()
        near = val.nearest_score()
        chosen = None
        for c in val.ranking():  # the best setting that builds from all samples
            if not (means[c] < LOO_MARGIN * near):
                continue
            try:
                self._build(models, P, val.candidates[c], val, warn=False, data=data)
                chosen = val.candidates[c]
                break
            except (ValueError, np.linalg.LinAlgError):
                continue
        if chosen is not None:
            self.validation_ = replace(val, chosen=chosen, fallback=False)
            self._warn_unmatched()
            return self
        for c in val.ranking():  # the modes of the best that builds, for the record
            try:
                self._build(models, P, val.candidates[c], val, warn=False)
                break
            except (ValueError, np.linalg.LinAlgError):
                continue
        else:
            self._build_empty(models, P)
        self.validation_ = replace(val, chosen=None, fallback=True)
        self.fallback_ = True
        self._library = models
        self._warn_fallback(best)
        return self

    def _default_choice(self, q: int) -> Candidate:
        """The settings without validation: the given ones, ``"auto"`` as before validation."""
        return Candidate("continuation" if self.match == "auto" else self.match,
                         "joint" if self.block == "auto" else self.block, int(self.n_pairs),
                         ("lagrange" if q == 1 else "rbf") if self.weights == "auto" else self.weights,
                         "modal" if self.scheme == "auto" else self.scheme)

    def _candidates(self, q: int) -> list[Candidate]:
        """The settings leave-one-sample-out chooses among, the default first: match and block
        (veering groups as joint blocks or none; assignment has none) where ``"auto"``, n_pairs
        down to 1, weights where ``"auto"``."""
        first = self._default_choice(q)
        matches = ["continuation", "assignment"] if self.match == "auto" else [self.match]
        weights = (["lagrange", "linear"] if q == 1 else ["rbf", "regress"]) if self.weights == "auto" \
            else [self.weights]
        pairs = list(range(int(self.n_pairs), 0, -1)) or [0]
        schemes = ["modal", "inverse"] if self.scheme == "auto" else [self.scheme]
        out = []
        for match in matches:
            blocks = ["none"] if match == "assignment" and self.block == "auto" else \
                (["joint", "none"] if self.block == "auto" else [self.block])
            out += [Candidate(match, block, k, w, sc) for block in blocks for k in pairs for w in weights
                    for sc in schemes]
        return [first] + [c for c in out if c != first]

    def _modal_blocks(self) -> bool:
        """Veering groups' blocks in modal variables (A'^2, A' B'), else direct (A', B'): the
        constructor's scheme, so that the candidates of one build differ only in ``_interpolate``."""
        return self.scheme != "direct"

    def model_for(self, p: Any, cand: Candidate) -> StateSpace:
        """The model at ``p`` with ``cand``'s weights and scheme on this build (its match, block
        and pairs): what leave-one-sample-out scores."""
        keep = self.choice_
        self.choice_ = replace(keep, weights=cand.weights, scheme=cand.scheme)
        try:
            return self.at_weights(self.weights_for(p)).model_
        finally:
            self.choice_ = keep

    def _fold(self, cand: Candidate, models: list[StateSpace], P: np.ndarray,
              data: list[Data]) -> ParametricROM:
        """A ROM of ``cand``'s settings from some samples' models and data (a leave-one-out
        fold), quiet."""
        rom = copy.copy(self)
        rom.verbose = False
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ParametricFallbackWarning)
            return rom._build(models, P, cand, Validation("fold", cand), warn=False, data=data)

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
        sample) instead of fitting the base estimator: ``fit`` without its first step and, having
        no data, without validation (the settings as given). Returns self."""
        models = list(models)
        P = self._check_samples(params, len(models))
        if not hasattr(self, "estimators_") or len(self.estimators_) != len(models):
            self.estimators_ = []
        return self._build(models, P, self._default_choice(P.shape[1]), Validation("no data", None))

    def _build(self, models: list[StateSpace], P: np.ndarray, cand: Candidate, val: Validation,
               warn: bool = True, data: list[Data] | None = None) -> ParametricROM:
        """The ROM of settings ``cand`` from the samples' models at P (n, q) (and their data:
        with ``residues="data"`` the kept modes' residues and D are fitted to them)."""
        self.choice_ = cand
        self.validation_ = val if val.chosen is not None or val.rule == "loo" else \
            Validation(val.rule, cand)
        self.fallback_ = False
        forms = [_modal_form(ss) for ss in models]
        prs = [f[0] for f in forms]
        self.dc_ = np.stack([f[1] for f in forms])
        self.params_ = P
        self.dt_ = float(prs[0].dt)
        self._scale = _range_scale(P)
        # 1-D: a chain in parameter order; else each sample matched to its nearest matched one
        order = np.argsort(P[:, 0], kind="stable") if P.shape[1] == 1 else np.arange(len(P))
        edges = [(int(order[i]), int(order[i - 1])) for i in range(1, len(P))] if P.shape[1] == 1 \
            else _tree(P / self._scale)
        root = int(order[0])
        self.unmatched_: list[tuple[int, complex, float]] = []
        found = [self._match([_modes(pr, real) for pr in prs], root, edges, keep, P / self._scale, not real)
                 for real, keep in ((False, cand.n_pairs), (True, int(self.n_real))) if keep]
        n_fb = sum(f.fs.shape[1] for f in found)
        if sum(f.s.shape[1] for f in found) + n_fb == 0:
            raise ValueError("no mode could be matched across the samples (see unmatched_)")
        self._n_pairs_kept = found[0].s.shape[1] if cand.n_pairs else 0
        self._s = np.hstack([f.s for f in found])  # (n, r) continuous poles
        self._R = np.concatenate([f.R for f in found], axis=1)  # (n, r, p, m) continuous residues
        self._groups = found[0].groups if cand.n_pairs else []
        self._blocks = found[0].blocks if cand.n_pairs else []
        self._fb_s = np.hstack([f.fs for f in found])  # (n, f) fallback modes, NaN where absent
        self._fb_R = np.concatenate([f.fR for f in found], axis=1)
        self._fb_pair = np.concatenate([np.full(f.fs.shape[1], i == 0 and cand.n_pairs > 0)
                                        for i, f in enumerate(found)])
        self.D_ = np.stack([pr.D.real for pr in prs])
        if data is not None and self.residues == "data":
            self._refit_residues(data, [f.R for f in found])
        self._joints = [fit_joint(self._s[:, cols], self._R[:, cols], P, self._scale, b.X, b.Y, b.C,
                                  self._modal_blocks()) if cand.block == "joint" else None
                        for cols, b in zip(self._groups, self._blocks)]
        self._set_discrete()
        if warn:
            self._warn_unmatched()
        return self

    def _refit_residues(self, data: list[Data], copied: list[np.ndarray]) -> None:
        """Each sample's kept modes' residues (matched and fallback) and D fitted to its data
        (:mod:`node.sysid.prom_residues`), its poles kept; a sample whose fit fails keeps its
        model's. The veering groups' common-basis blocks are rebuilt from the new residues (a
        group without one then keeps the copied residues, ``copied``: ``_match``'s R per kind)."""
        pair = np.arange(self._s.shape[1]) < self._n_pairs_kept
        for i, runs in enumerate(data):
            have = np.isfinite(self._fb_s[i])
            s = np.r_[self._s[i], self._fb_s[i, have]]
            flags = np.r_[pair, self._fb_pair[have]]
            z = np.exp(s * self.dt_)
            got = _RESIDUES.get([z.real, z.imag, flags, *[a for run in runs for a in run]],
                                partial(fit_residues, z, flags, runs))
            if got is None:
                continue
            near1 = np.abs(z - 1.0) < 1e-12
            ratio = np.where(near1, 1.0 / self.dt_, s / np.where(near1, 1.0, z - 1.0))
            R = got[0] * ratio[:, None, None]
            r = self._s.shape[1]
            self._R[i] = R[:r]
            self._fb_R[i, have] = R[r:]
            self.D_[i] = got[1]
        before = np.concatenate(copied, axis=1)
        for g, cols in enumerate(self._groups):
            block = _common_basis(self._s[:, cols], self._R[:, cols], self._modal_blocks())
            if block is None:
                self._R[:, cols] = before[:, cols]
            else:
                self._blocks[g] = block

    def _build_empty(self, models: list[StateSpace], P: np.ndarray) -> None:
        """No setting builds from all samples: no modes (``at`` returns the nearest sample's model)."""
        n, (p, m) = len(models), models[0].D.shape
        self.choice_ = self._default_choice(P.shape[1])
        self.params_, self.dt_, self._scale = P, float(models[0].dt), _range_scale(P)
        self.D_ = np.stack([ss.D for ss in models])
        self.dc_ = np.stack([static_gain(ss) for ss in models])
        self._s, self._R = np.zeros((n, 0), complex), np.zeros((n, 0, p, m), complex)
        self._fb_s, self._fb_R = self._s.copy(), self._R.copy()
        self._fb_pair = np.zeros(0, bool)
        self._n_pairs_kept, self._groups, self._blocks, self._joints = 0, [], [], []
        self._set_discrete()

    def _mode_names(self) -> str:
        """The kept modes' frequencies at the first sample (Hz when dt is in s), and the unmatched."""
        f = np.abs(self._s[0].imag) / (2 * np.pi) if self._s.size else np.zeros(0)
        out = "modes at " + (", ".join(f"{v:.4g}" for v in f) or "none") + " Hz"
        if self.unmatched_:
            out += "; unmatched: " + ", ".join(
                f"{abs(np.angle(z)) / (2 * np.pi * self.dt_):.4g} Hz (sample {i}, cost {c:.3g})"
                for i, z, c in self.unmatched_)
        return out

    def _warn_unmatched(self) -> None:
        """One warning when modes enter the model as the nearest sample's (no match, ``fallback``)."""
        if self.verbose and self._fb_s.shape[1]:
            warnings.warn(f"{type(self).__name__}: {self._fb_s.shape[1]} mode(s) have no match within "
                          f"tol {self.tol:g} across the samples and enter the model at p as the nearest "
                          f"sample's ({self._mode_names()})", ParametricFallbackWarning, stacklevel=3)

    def _warn_fallback(self, best: tuple[Candidate, float]) -> None:
        """The one warning of a ROM whose ``at`` returns the nearest sample's model."""
        near = self.validation_.nearest_score()
        held = ", ".join(str(i) for i in self.validation_.held_out)
        why = (f"no setting beats {LOO_MARGIN:g} x the nearest sample's model by leave-one-sample-out on "
               f"sample(s) {held} (best {best[0].label()}: eps_td {best[1]:.3g}, nearest sample's model "
               f"{near:.3g})") if best[1] >= LOO_MARGIN * near or not np.isfinite(best[1]) else \
            f"no setting builds from all samples (best by leave-one-sample-out: {best[0].label()})"
        warnings.warn(f"{type(self).__name__}: {why}; at(p) returns the nearest sample's model "
                      f"({self._mode_names()})", ParametricFallbackWarning, stacklevel=3)

    def _set_discrete(self) -> None:
        self.groups_ = [list(g) for g in self._groups]
        z = np.exp(self._s * self.dt_)
        self.residues_ = self._R * ((z - 1.0) / self._s)[:, :, None, None]
        self.poles_ = z

    def _match(self, modes: list[_Modes], root: int, edges: list[tuple[int, int]], keep: int,
               P: np.ndarray, pairs: bool) -> _Matched:
        """Tracks from every mode of the root sample, linked along ``edges`` by assignment on the
        cost to the parent's mode or its continuation (``_predict``); the ``keep`` with the largest
        mean peak share; complex tracks that cross or come within ``veer_gap`` of each other
        grouped (matched as sets, modelled as blocks); tracks (groups) with a link above tol
        reported and kept aside for the fallback."""
        n = len(modes)
        k0 = len(modes[root].s)
        track = np.full((n, k0), -1)
        track[root] = np.arange(k0)
        link = np.zeros((n, k0))  # cost of each track's link into each sample (root 0)
        turn = np.zeros((n, k0))  # 1 - MAC_out MAC_in of the link
        parent_of = dict(edges)
        for child, parent in edges:
            rows = np.where(track[parent] >= 0)[0]
            idx = track[parent, rows]
            pm = _Modes(modes[parent].s[idx], modes[parent].R[idx], modes[parent].share[idx])
            pred = None
            gp = parent_of.get(parent)
            cont = self.choice_.match == "continuation"
            if cont and gp is not None and np.all(track[gp, rows] >= 0):
                dp, dc = P[parent] - P[gp], P[child] - P[parent]
                tt = float(dc @ dp / (dp @ dp)) if dp @ dp > 0 else 0.0
                pred = _predict(pm.s, modes[gp].s[track[gp, rows]], tt)
            cost = _cost(pm, modes[child], self.mac_weight, pred, SHARE_WEIGHT if cont else 0.0)
            r, c = linear_sum_assignment(cost)
            track[child, rows[r]] = c
            link[child, rows] = np.inf
            link[child, rows[r]] = cost[r, c]
            ua, va = _directions(pm.R[r])
            ub, vb = _directions(modes[child].R[c])
            turn[child, rows[r]] = 1.0 - np.diag(mac(ua, ub) * mac(va, vb))
            link[child, track[parent] < 0] = np.inf
        share = np.array([[modes[i].share[t] if t >= 0 else 0.0 for t in track[i]] for i in range(n)])
        ranked = [int(j) for j in np.argsort(-share.mean(axis=0), kind="stable")[:keep]]
        complete = np.all(track >= 0, axis=0)
        groups = self._groups_of([j for j in ranked if complete[j]], modes, track, edges, turn, link) \
            if pairs and self.choice_.match == "continuation" and self.choice_.block != "none" else []
        blocks: dict[int, _Block] = {}
        unaligned: list[int] = []
        for gi, grp in enumerate(groups):  # a group's links cost as sets
            for child, parent in edges:
                sets = [_Modes(modes[i].s[track[i, grp]], modes[i].R[track[i, grp]],
                               modes[i].share[track[i, grp]]) for i in (parent, child)]
                link[child, grp] = _set_cost(sets[0], sets[1], self.mac_weight)
            block = _common_basis(np.array([modes[i].s[track[i, grp]] for i in range(n)]),
                                  np.array([modes[i].R[track[i, grp]] for i in range(n)]),
                                  self._modal_blocks())
            if block is None:  # no common basis: the group is unreliable
                unaligned += grp
            else:
                blocks[gi] = block
        ok = np.zeros((n, k0), dtype=bool)  # the track is its mode at this sample (no bad link above it)
        ok[root] = True
        for child, parent in edges:
            ok[child] = ok[parent] & (track[child] >= 0) & (link[child] <= self.tol)
        whole = np.all(ok, axis=0)
        good = [j for j in ranked if bool(whole[j]) and j not in unaligned]
        for j in ranked:
            if j not in good:  # the first bad link, or (no common basis for its group) the root
                bad = [(i, link[i, j]) for i, _ in edges if ok[parent_of[i], j] and not ok[i, j]]
                i, cst = bad[0] if bad else (root, float("inf"))
                pole = complex(np.exp(modes[root].s[j] * self.dt_))
                self.unmatched_.append((int(i), pole, float(cst)))
                log.log(logging.WARNING if self.verbose else logging.DEBUG,
                        "the mode at z = %.5g%+.5gj of sample %d has no match within tol %.3g at "
                        "sample %d (cost %.3g): %s", pole.real, pole.imag, root, self.tol, i, cst,
                        "the nearest sample's mode is used" if self.fallback == "nearest" else "left out")
        pm_ = modes[root].R.shape[1:]

        def take(cols: list[int], mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
            s = np.full((n, len(cols)), np.nan + 0j)
            R = np.full((n, len(cols), *pm_), np.nan + 0j)
            for i in range(n):
                for q, j in enumerate(cols):
                    if track[i, j] >= 0 and (mask is None or mask[i, j]):
                        s[i, q], R[i, q] = modes[i].s[track[i, j]], modes[i].R[track[i, j]]
            return s, R

        s, R = take(good)
        fb = [j for j in ranked if j not in good] if self.fallback == "nearest" else []
        fs, fR = take(fb)  # each sample's own mode of the track, matched up to it or not
        kept = [(gi, [good.index(j) for j in grp]) for gi, grp in enumerate(groups)
                if all(j in good for j in grp)]
        return _Matched(s, R, [cols for _, cols in kept], [blocks[gi] for gi, _ in kept], fs, fR)

    def _groups_of(self, cols: list[int], modes: list[_Modes], track: np.ndarray,
                   edges: list[tuple[int, int]], turn: np.ndarray, link: np.ndarray) -> list[list[int]]:
        """Groups (of two or more) among the tracks ``cols`` that cross between neighbouring samples or
        come within ``veer_gap`` (relative frequency gap) of each other at a sample, where the
        shape of either turns (``turn`` (n, k): 1 - MAC_out MAC_in of each track's link into each
        sample) by more than ``ROTATION``: modes that cross with fixed shapes stay one-to-one; and
        two tracks that both turn at a link where, as a set, they cost less than apart (veering)."""
        label = {j: j for j in cols}

        def find(j: int) -> int:
            while label[j] != j:
                j = label[j]
            return j

        if self.veer_gap <= 0:
            return []
        for child, parent in edges:
            wc = {j: abs(modes[child].s[track[child, j]]) for j in cols}
            wp = {j: abs(modes[parent].s[track[parent, j]]) for j in cols}
            for x in range(len(cols)):
                for y in range(x + 1, len(cols)):
                    a, b = cols[x], cols[y]
                    near = min(abs(w[a] - w[b]) / max(w[a], w[b]) for w in (wc, wp)) <= self.veer_gap
                    ta, tb = turn[child, a], turn[child, b]
                    if (near or (wc[a] - wc[b]) * (wp[a] - wp[b]) < 0) and max(ta, tb) > ROTATION:
                        label[find(a)] = find(b)  # a crossing or near-crossing where shapes turn
                    elif min(ta, tb) > ROTATION:  # both turn: a veering if they span what they spanned
                        sets = [_Modes(modes[i].s[track[i, [a, b]]], modes[i].R[track[i, [a, b]]],
                                       modes[i].share[track[i, [a, b]]]) for i in (parent, child)]
                        if _set_cost(sets[0], sets[1], self.mac_weight) < max(link[child, a], link[child, b]):
                            label[find(a)] = find(b)
        out: dict[int, list[int]] = {}
        for j in cols:
            out.setdefault(find(j), []).append(j)
        return [g for g in out.values() if len(g) > 1]

    # --- interpolate --------------------------------------------------------------------------
    def _require_fit(self) -> None:
        if not hasattr(self, "poles_"):
            from sklearn.exceptions import NotFittedError
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet: call fit first")

    def weights_at(self, p: Any) -> np.ndarray:
        """Interpolation weights (n,) of the samples at parameter value ``p`` (scalar or (q,))."""
        return self.weights_for(p)

    def weights_for(self, p: Any, kind: str | None = None) -> np.ndarray:
        """Weights (n,) at ``p`` of rule ``kind`` (one of ``WEIGHTS`` but auto; None: ``choice_``'s)."""
        self._require_fit()
        P = self.params_
        x = np.asarray(p, dtype=float).reshape(-1)
        if x.size != P.shape[1]:
            raise ValueError(f"the model has {P.shape[1]} parameter(s), got {x.size} value(s)")
        if self.clip:
            x = np.clip(x, P.min(axis=0), P.max(axis=0))
        kind = self.choice_.weights if kind is None else kind
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
        scheme = self.choice_.scheme
        if scheme == "inverse":  # 1 / w^2, 2 zeta w / w^2 and R_s / w: a mass-like parameter
            w0 = np.abs(s)
            w2 = 1.0 / np.maximum(w @ (1.0 / w0 ** 2), (self.dt_ / np.pi) ** 2)  # below Nyquist
            c = np.maximum(w2 * (w @ (-2.0 * s.real / w0 ** 2)), 2 * tiny)
            wd = np.sqrt(np.maximum(w2 - c ** 2 / 4, tiny ** 2))
            si = np.where(np.arange(s.shape[1]) < k, -c / 2 + 1j * wd, -c / 2 + 0j)
            Ri = np.einsum("i,ijpm->jpm", w, R / w0[:, :, None, None]) * np.sqrt(w2)[:, None, None]
        elif scheme == "modal":
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

    def _block_modes(self, block: _Block, joint: JointBlock | None, w: np.ndarray, guess: np.ndarray,
                     lo: complex, hi: complex) -> tuple[np.ndarray, np.ndarray]:
        """A veering group's continuous poles (g,) and residues (g, p, m) for sample weights w:
        its joint fit at the parameter value w @ params_ (``block="joint"``), else its common-basis
        realisation interpolated (the poles from the interpolated characteristic polynomial);
        diagonalised; the modes in the order of ``guess`` (their one-to-one interpolation),
        Re s < 0 (``clip``: within lo..hi)."""
        modal = self._modal_blocks()
        if joint is not None:  # the weights reproduce linear functions: w @ params_ is p
            s, R = joint_modes(*joint.at(w @ self.params_))
        else:
            X = np.einsum("i,ijk->jk", w, block.X)
            ev, V = np.linalg.eig(X)  # the modes' shapes
            roots = np.roots(w @ block.poly)  # their eigenvalues, from the interpolated polynomial
            r, c = linear_sum_assignment(np.abs(ev[:, None] - roots[None, :]))
            ev = roots[c[np.argsort(r)]]
            # modal: X = A'^2, A' = i sqrt(-X), the upper half plane's branch; Y = A' B'
            s = 1j * np.sqrt(-ev) if modal else ev
            # (a defective interpolated block: least squares, not an error)
            Bm = np.linalg.pinv(V) @ np.einsum("i,ijk->jk", w, block.Y)
            Bm = Bm / s[:, None] if modal else Bm
            R = np.einsum("pj,jm->jpm", np.einsum("i,ijk->jk", w, block.C) @ V, Bm)
        tiny = 1e-9 / self.dt_
        s = np.minimum(s.real, -tiny) + 1j * np.maximum(s.imag, tiny)
        if self.clip:
            s = np.clip(s.real, lo.real, hi.real) + 1j * np.clip(s.imag, lo.imag, hi.imag)
        r, c = linear_sum_assignment(np.abs(guess[:, None] - s[None, :]))
        order = c[np.argsort(r)]
        return s[order], R[order]

    def _statespace(self, s: np.ndarray, R: np.ndarray, D: np.ndarray,
                    pair: np.ndarray | None = None) -> StateSpace:
        """Real state space of continuous modes s (r,), R (r, p, m): ``pair`` (r,) marks the
        complex pairs (default: the first ``_n_pairs_kept``), the others are real poles."""
        z = np.exp(s * self.dt_)
        Rz = R * ((z - 1.0) / s)[:, None, None]
        pair = np.arange(len(s)) < self._n_pairs_kept if pair is None else pair
        poles = np.r_[z[pair], z[pair].conj(), z[~pair].real + 0j]
        res = np.concatenate([Rz[pair], Rz[pair].conj(), Rz[~pair].real + 0j])
        return PoleResidue(poles, res, D.astype(complex), self.dt_).to_statespace()

    def _modes_at(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous poles (r',), residues (r', p, m) and pair flags (r',) of the model for
        sample weights w: matched modes interpolated (groups as blocks), then the fallback
        modes of the sample of largest weight (the nearest) that has them."""
        s, R = self._interpolate(w)
        for grp, block, joint in zip(self._groups, self._blocks, self._joints):
            lo = complex(self._s[:, grp].real.min(), self._s[:, grp].imag.min())
            hi = complex(self._s[:, grp].real.max(), self._s[:, grp].imag.max())
            s[grp], R[grp] = self._block_modes(block, joint, w, s[grp], lo, hi)
        pair = np.arange(len(s)) < self._n_pairs_kept
        if self._fb_s.shape[1]:
            i = int(np.argmax(w))
            have = np.isfinite(self._fb_s[i])
            s, R = np.r_[s, self._fb_s[i, have]], np.concatenate([R, self._fb_R[i, have]])
            pair = np.r_[pair, self._fb_pair[have]]
        return s, R, pair

    def at(self, p: Any) -> ParametricModel:
        """The model at parameter value ``p`` (scalar or (q,)): real, stable, discrete-time
        (``fallback_``: the nearest sample's fitted model, in range-scaled distance)."""
        w = self.weights_at(p)
        if self.fallback_:
            x = np.asarray(p, dtype=float).reshape(-1)
            return ParametricModel(self._library[nearest_sample(self.params_, self._scale, x,
                                                                range(len(self.params_)))])
        return self.at_weights(w)

    def at_weights(self, w: np.ndarray) -> ParametricModel:
        """The model for sample weights w (n,) (``weights_at`` gives them for a parameter value;
        ``fallback_``: the fitted model of the sample of largest weight)."""
        self._require_fit()
        w = np.asarray(w, float)
        if self.fallback_:
            return ParametricModel(self._library[int(np.argmax(w))])
        s, R, pair = self._modes_at(w)
        D = np.einsum("i,ipm->pm", w, self.D_)
        if self.static:
            bare = self._statespace(s, R, np.zeros_like(D), pair)
            D = np.einsum("i,ipm->pm", w, self.dc_) - static_gain(bare)
        return ParametricModel(self._statespace(s, R, D, pair))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """What ``at`` needs, as real arrays (``from_arrays`` restores it): no estimators."""
        self._require_fit()
        group = np.full(self._s.shape[1], -1)
        for g, cols in enumerate(self._groups):
            group[cols] = g
        return {"rom_format": np.array([FORMAT]), "rom_s_re": self._s.real, "rom_s_im": self._s.imag,
                "rom_R_re": self._R.real, "rom_R_im": self._R.imag, "rom_D": self.D_, "rom_dc": self.dc_,
                "rom_params": self.params_, "rom_scale": self._scale,
                "rom_meta": np.array([self.dt_, float(self._n_pairs_kept)]), "rom_group": group,
                "rom_fb_s_re": self._fb_s.real, "rom_fb_s_im": self._fb_s.imag,
                "rom_fb_R_re": self._fb_R.real, "rom_fb_R_im": self._fb_R.imag, "rom_fb_pair": self._fb_pair,
                **self._joint_arrays(), **self._choice_arrays()}

    def _choice_arrays(self) -> dict[str, np.ndarray]:
        """What validation chose beyond the constructor's parameters (none without validation):
        the weights (an index of ``WEIGHTS``) and, when ``fallback_``, the samples' models
        (A (n, k, k), B (n, k, m), C (n, p, k), D (n, p, m))."""
        out: dict[str, np.ndarray] = {}
        if self.choice_.weights != self._default_choice(self.params_.shape[1]).weights:
            out["rom_weights"] = np.array([WEIGHTS.index(self.choice_.weights)])
        if self.choice_.scheme != self._default_choice(self.params_.shape[1]).scheme:
            out["rom_scheme"] = np.array([SCHEMES.index(self.choice_.scheme)])
        if self.fallback_:
            lib = self._library
            if len({ss.A.shape for ss in lib}) > 1:
                raise ValueError("the samples' models differ in size: a fallen-back ROM cannot be stored")
            out.update({f"rom_library_{k}": np.stack([getattr(ss, k) for ss in lib]) for k in "ABCD"})
        return out

    def _joint_arrays(self) -> dict[str, np.ndarray]:
        """The groups' joint fits (format 3), zero-padded to the largest group: X (G, k, g, g),
        Y (G, g, m), C (G, p, g) as real and imaginary parts, ok (G,) (False: that group is
        interpolated per sample), exps (k, q), center (q,); G = 0 when no group has a joint fit."""
        joints = self._joints if any(j is not None for j in self._joints) else []
        (p, m), q = self.D_.shape[1:], self.params_.shape[1]
        first = next((j for j in joints if j is not None), None)
        g = max((len(cols) for cols in self._groups), default=0) if joints else 0
        exps = first.exps if first is not None else np.zeros((0, q), int)
        X = np.zeros((len(joints), len(exps), g, g), complex)
        Y = np.zeros((len(joints), g, m), complex)
        C = np.zeros((len(joints), p, g), complex)
        for i, j in enumerate(joints):
            if j is not None:
                h = j.X.shape[1]
                X[i, :, :h, :h], Y[i, :h], C[i, :, :h] = j.X, j.Y, j.C
        center = first.center if first is not None else self.params_.mean(axis=0)
        return {"rom_joint_X_re": X.real, "rom_joint_X_im": X.imag, "rom_joint_Y_re": Y.real,
                "rom_joint_Y_im": Y.imag, "rom_joint_C_re": C.real, "rom_joint_C_im": C.imag,
                "rom_joint_ok": np.array([j is not None for j in joints], bool),
                "rom_joint_exps": exps, "rom_joint_center": center}

    @classmethod
    def from_arrays(cls, arrays: Any, **params: Any) -> ParametricROM:
        """A fitted ROM from ``to_arrays``' output and the constructor's parameters (no base
        estimator: it cannot be refitted, only evaluated). Reads formats 1 to 3 (1 and 2: the
        groups interpolated per sample, as they were fitted)."""
        version = int(np.asarray(arrays["rom_format"])[0])
        if version not in (1, 2, FORMAT):
            raise ValueError(f"parametric model arrays of format {version}; this version reads 1 to {FORMAT}")
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
        n, (p, m) = len(rom.params_), rom.D_.shape[1:]
        if version == 1:
            group = np.full(rom._s.shape[1], -1)
            rom._fb_s, rom._fb_R = np.zeros((n, 0), complex), np.zeros((n, 0, p, m), complex)
            rom._fb_pair = np.zeros(0, bool)
        else:
            group = np.asarray(arrays["rom_group"], int)
            rom._fb_s = np.asarray(arrays["rom_fb_s_re"]) + 1j * np.asarray(arrays["rom_fb_s_im"])
            rom._fb_R = np.asarray(arrays["rom_fb_R_re"]) + 1j * np.asarray(arrays["rom_fb_R_im"])
            rom._fb_pair = np.asarray(arrays["rom_fb_pair"], bool)
        rom._groups = [[int(j) for j in np.where(group == g)[0]]
                       for g in range(int(group.max(initial=-1)) + 1)]
        blocks = [_common_basis(rom._s[:, cols], rom._R[:, cols], rom._modal_blocks())
                  for cols in rom._groups]
        if any(b is None for b in blocks):
            raise ValueError("parametric model arrays hold a group without a common basis")
        rom._blocks = [b for b in blocks if b is not None]
        rom._joints = [None] * len(rom._groups)
        if version >= 3 and len(arrays["rom_joint_X_re"]):
            X = np.asarray(arrays["rom_joint_X_re"]) + 1j * np.asarray(arrays["rom_joint_X_im"])
            Y = np.asarray(arrays["rom_joint_Y_re"]) + 1j * np.asarray(arrays["rom_joint_Y_im"])
            C = np.asarray(arrays["rom_joint_C_re"]) + 1j * np.asarray(arrays["rom_joint_C_im"])
            exps = np.asarray(arrays["rom_joint_exps"], int)
            center = np.asarray(arrays["rom_joint_center"], float)
            q = rom.params_.shape[1]
            if len(X) != len(rom._groups) or len(arrays["rom_joint_ok"]) != len(X) or \
                    exps.shape != (X.shape[1], q) or center.shape != (q,):
                raise ValueError("parametric model arrays hold joint fits that are not their groups'")
            ok = np.asarray(arrays["rom_joint_ok"], bool)
            rom._joints = [JointBlock(X[i][:, :len(g), :len(g)], Y[i, :len(g)], C[i, :, :len(g)], exps,
                                      center, rom._scale) if ok[i] else None
                           for i, g in enumerate(rom._groups)]
        rom.choice_ = rom._default_choice(rom.params_.shape[1])
        if "rom_weights" in arrays:
            rom.choice_ = replace(rom.choice_, weights=WEIGHTS[int(np.asarray(arrays["rom_weights"])[0])])
        if "rom_scheme" in arrays:
            rom.choice_ = replace(rom.choice_, scheme=SCHEMES[int(np.asarray(arrays["rom_scheme"])[0])])
        rom.choice_ = replace(rom.choice_, n_pairs=rom._n_pairs_kept)
        rom.validation_ = Validation("restored from arrays", rom.choice_)
        rom.fallback_ = "rom_library_A" in arrays
        if rom.fallback_:
            lib = [np.asarray(arrays[f"rom_library_{k}"], float) for k in "ABCD"]
            rom._library = [StateSpace(lib[0][i], lib[1][i], lib[2][i], lib[3][i], rom.dt_) for i in range(n)]
            rom.validation_ = Validation("restored from arrays", None, fallback=True)
        rom._set_discrete()
        return rom

    def library_model(self, i: int) -> StateSpace:
        """The matched modes of sample ``i`` alone, and the fallback modes it has, as a state
        space (what ``at`` reproduces there; a veering group's joint fit only approximately,
        within the samples' identification errors)."""
        self._require_fit()
        have = np.isfinite(self._fb_s[i])
        pair = np.r_[np.arange(self._s.shape[1]) < self._n_pairs_kept, self._fb_pair[have]]
        return self._statespace(np.r_[self._s[i], self._fb_s[i, have]],
                                np.concatenate([self._R[i], self._fb_R[i, have]]), self.D_[i], pair)
