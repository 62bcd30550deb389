"""Contextual characteristic curves (dissertation section 3.4, 3.4.1, figures 3.4-3.6).

Within one OC the tracked order's amplitude is dispersed although the speed is steady: the
engine's thermal state moves on. Per OC, the plateau samples of every run are clustered in
the space of the gas-path temperatures (tA, tF, tI by default, standardised) by a
Dirichlet-process Gaussian mixture (scikit-learn's ``BayesianGaussianMixture``): the
clusters follow one another in time (figure 3.4 (b)), so each is a stage of the OC's thermal
evolution. Carried onto the characteristic curve, each cluster has its own mean amplitude
and spread; their posteriors come from a Gibbs sampler with a Student-t likelihood, robust to
outliers (section 3.4.1, figure 3.6).

``context_curves`` does it for every OC; ``gibbs_student_t`` is the sampler alone and
``out_of_order`` measures how sequential the clusters are. Pure numerics: no files, no plots
(``replay.views.context_plots`` draws the figures).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from node.contract import FS
from node.contract.schedule import Schedule
from node.training.dataset import fill_gaps, segment_runs
from node.training.runs import Run

log = logging.getLogger(__name__)

TEMPERATURES = ("tA", "tF", "tI")  # the gas-path temperatures of figure 3.4 (a)


# -- the Gibbs sampler -----------------------------------------------------------------------
@dataclass(frozen=True)
class NIGPrior:
    """Normal-inverse-gamma prior: mu | sigma^2 ~ N(m0, sigma^2 / k0), sigma^2 ~ IG(a0, b0)
    (shape a0, scale b0), in the target's units (mm/s; b0 in (mm/s)^2).

    >>> NIGPrior.weak(np.array([1.0, 2.0, 3.0])).m0
    2.0
    """

    m0: float
    k0: float
    a0: float
    b0: float

    @classmethod
    def weak(cls, y: np.ndarray) -> NIGPrior:
        """A weak prior scaled to the data y (n,): centred on its median, worth 1 % of a sample
        for mu and one sample for sigma^2 at 1 % of its robust spread."""
        y = np.asarray(y, float)
        med = float(np.median(y))
        mad = 1.4826 * float(np.median(np.abs(y - med)))
        spread = mad if mad > 0 else float(np.std(y)) or 1.0
        return cls(med, 0.01, 1.0, (0.1 * spread) ** 2)


@dataclass(frozen=True)
class Posterior:
    """Posterior samples of a cluster's amplitude mean and standard deviation.

    mu, sigma: (S,) chain after burn-in and thinning, mm/s; n: data points; nu: the Student-t
    degrees of freedom used (inf: normal likelihood).
    """

    mu: np.ndarray
    sigma: np.ndarray
    n: int
    nu: float


def gibbs_student_t(y: np.ndarray, nu: float = 4.0, prior: NIGPrior | None = None,
                    n_iter: int = 3000, burn: int = 500, thin: int = 2,
                    seed: int | np.random.Generator = 0) -> Posterior:
    """Posterior of (mu, sigma) for y_i ~ Student-t_nu(mu, sigma^2) by Gibbs sampling.

    Hand-written: the model is small and no installed library offers this sampler (PyMC /
    Stan would be heavy dependencies for four conditionals). The Student-t is a scale mixture
    of normals: y_i | lambda_i ~ N(mu, sigma^2 / lambda_i), lambda_i ~ Gamma(nu/2, rate nu/2),
    so with the normal-inverse-gamma prior every conditional is conjugate:

    * lambda_i | . ~ Gamma((nu + 1) / 2, rate (nu + (y_i - mu)^2 / sigma^2) / 2)
    * mu | . ~ N((k0 m0 + sum lambda_i y_i) / (k0 + sum lambda_i), sigma^2 / (k0 + sum lambda_i))
    * sigma^2 | . ~ IG(a0 + (n + 1) / 2, b0 + (sum lambda_i (y_i - mu)^2 + k0 (mu - m0)^2) / 2)

    An outlier gets a small lambda_i and so little weight. nu = inf fixes lambda_i = 1 (the
    normal likelihood, whose posterior is the normal-inverse-gamma one in closed form).

    y: (n,) finite amplitudes, mm/s (n >= 1); prior: default ``NIGPrior.weak(y)``; n_iter
    sweeps of which the first ``burn`` are dropped and every ``thin``-th kept after; seed: a
    numpy Generator or its seed. Returns (S,) samples, S = ceil((n_iter - burn) / thin).

    >>> rng = np.random.default_rng(1)
    >>> p = gibbs_student_t(np.r_[rng.normal(5.0, 0.5, 200), 40.0], seed=2)
    >>> round(float(p.mu.mean()), 1), p.mu.shape  # the outlier at 40 hardly moves it
    (5.0, (1250,))
    """
    y = np.asarray(y, float).ravel()
    if y.size == 0 or not np.isfinite(y).all():
        raise ValueError("gibbs_student_t needs at least one finite value and no NaN")
    if not (nu > 0) or not (0 <= burn < n_iter) or thin < 1:
        raise ValueError(f"need nu > 0, 0 <= burn < n_iter and thin >= 1, got {nu}, {burn}, {n_iter}, {thin}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    pr = prior or NIGPrior.weak(y)
    n = y.size
    normal = math.isinf(nu)
    lam = np.ones(n)
    mu = float(np.median(y))
    sig2 = float(np.var(y)) or pr.b0 / max(pr.a0, 1.0) or 1.0
    keep = range(burn, n_iter, thin)
    mus, sig2s = np.empty(len(keep)), np.empty(len(keep))
    a_post = pr.a0 + 0.5 * (n + 1)
    j = 0
    for it in range(n_iter):
        if not normal:
            lam = rng.gamma(0.5 * (nu + 1.0), 1.0 / (0.5 * (nu + (y - mu) ** 2 / sig2)))
        slam = float(lam.sum())
        kn = pr.k0 + slam
        mu = float(rng.normal((pr.k0 * pr.m0 + float(lam @ y)) / kn, math.sqrt(sig2 / kn)))
        r = y - mu
        b_post = pr.b0 + 0.5 * (float(lam @ (r * r)) + pr.k0 * (mu - pr.m0) ** 2)
        sig2 = b_post / float(rng.gamma(a_post, 1.0))  # IG(a, b) = b / Gamma(a, 1)
        if it >= burn and (it - burn) % thin == 0:
            mus[j], sig2s[j] = mu, sig2
            j += 1
    return Posterior(mus, np.sqrt(sig2s), n, float(nu))


def nig_posterior(y: np.ndarray, prior: NIGPrior) -> tuple[float, float]:
    """The closed-form posterior means (E[mu], E[sigma^2]) of a normal likelihood under the
    normal-inverse-gamma prior (the sampler's nu = inf case; E[sigma^2] needs a_n > 1).

    >>> nig_posterior(np.array([1.0, 3.0]), NIGPrior(0.0, 0.0, 2.0, 1.0))
    (2.0, 1.0)
    """
    y = np.asarray(y, float)
    n, ybar = y.size, float(y.mean())
    kn = prior.k0 + n
    mn = (prior.k0 * prior.m0 + n * ybar) / kn
    an = prior.a0 + 0.5 * n
    bn = prior.b0 + 0.5 * float(((y - ybar) ** 2).sum()) + prior.k0 * n * (ybar - prior.m0) ** 2 / (2 * kn)
    return mn, bn / (an - 1.0)


def batch_means_se(x: np.ndarray, n_batches: int = 20) -> float:
    """Monte Carlo standard error of the mean of a chain x (S,) by non-overlapping batch means.

    >>> round(batch_means_se(np.random.default_rng(0).normal(size=20000)), 3)
    0.008
    """
    x = np.asarray(x, float)
    size = x.size // n_batches
    if size < 1:
        raise ValueError(f"a chain of {x.size} samples cannot make {n_batches} batches")
    means = x[: size * n_batches].reshape(n_batches, size).mean(axis=1)
    return float(means.std(ddof=1) / math.sqrt(n_batches))


# -- the mixture per OC -----------------------------------------------------------------------
@dataclass
class OCContext:
    """One OC's contextual characteristic curve.

    Per plateau sample kept (N, decimated): run (index into the runs given), t (s since the
    epoch), elapsed (s since the run's plateau start), tau (the same as a fraction of that
    plateau, in [0, 1)), speed (rpm), y (the target, mm/s), X (N, c) the temperature channels
    (``channels``, °C) and labels (N,) the cluster of each, 0..k-1 ordered by mean tau.
    Per cluster (k): centres (k, c) its mean in temperature space (°C), weights (k,) its share
    of the samples, posteriors its (mu, sigma) posterior (``gibbs_student_t``); target: the
    amplitude's channel.
    """

    name: str
    oc: int
    channels: tuple[str, ...]
    run: np.ndarray
    t: np.ndarray
    elapsed: np.ndarray
    tau: np.ndarray
    speed: np.ndarray
    y: np.ndarray
    X: np.ndarray
    labels: np.ndarray
    centres: np.ndarray
    weights: np.ndarray
    posteriors: list[Posterior]
    target: str = ""

    @property
    def n_clusters(self) -> int:
        return len(self.posteriors)


@dataclass
class _Plateaus:
    """The decimated plateau samples of one OC over every run (see ``OCContext``)."""

    run: list[np.ndarray]
    t: list[np.ndarray]
    elapsed: list[np.ndarray]
    tau: list[np.ndarray]
    speed: list[np.ndarray]
    y: list[np.ndarray]
    X: list[np.ndarray]


def _plateau_samples(runs: list[Run], schedule: Schedule, target: str, channels: tuple[str, ...],
                     every: int) -> dict[int, dict[str, np.ndarray]]:
    """Per OC index, the plateau samples (every ``every``-th) of all runs where the target and
    every channel are measured (gaps held as the node holds them), concatenated."""
    cols = [schedule.switch, target, *channels]
    acc: dict[int, _Plateaus] = {}
    filled = []
    for r, run in enumerate(runs):
        missing = [c for c in cols if c not in run.channels]
        if missing:
            raise ValueError(f"run {r} lacks channel(s) {missing}")
        raw = np.column_stack([run.column(c) for c in cols])
        filled.append(fill_gaps(raw))
    for s in segment_runs(runs, schedule):
        n = s.stop - s.steady_start
        if n < every:
            continue
        idx = np.arange(s.steady_start, s.stop, every)
        rows = filled[s.run][idx]
        ok = np.isfinite(rows).all(axis=1)
        idx, rows = idx[ok], rows[ok]
        p = acc.setdefault(s.oc, _Plateaus([], [], [], [], [], [], []))
        p.run.append(np.full(idx.size, s.run))
        p.t.append(np.asarray(runs[s.run].t, float)[idx])
        p.elapsed.append((idx - s.steady_start) / FS)
        p.tau.append((idx - s.steady_start) / n)
        p.speed.append(rows[:, 0])
        p.y.append(rows[:, 1])
        p.X.append(rows[:, 2:])
    return {oc: {k: np.concatenate(getattr(p, k)) for k in _Plateaus.__dataclass_fields__}
            for oc, p in sorted(acc.items())}


def cluster_temperatures(X: np.ndarray, tau: np.ndarray, max_components: int = 5,
                         min_weight: float = 0.05, seed: int = 0, concentration: float | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dirichlet-process Gaussian mixture on the standardised X (N, c): (labels (N,), centres
    (k, c) in X's units, weights (k,)), the clusters ordered by the mean of tau (N,) (their
    time within the plateau). Components holding less than ``min_weight`` of the samples
    are dropped, their samples given to the likeliest kept one. concentration: the Dirichlet
    process's (scikit-learn's ``weight_concentration_prior``; default 1 / max_components;
    smaller favours fewer clusters)."""
    from sklearn.mixture import BayesianGaussianMixture

    X = np.asarray(X, float)
    N = X.shape[0]
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale[scale <= 1e-12 * (np.abs(mean) + 1.0)] = 1.0
    Z = (X - mean) / scale
    k = max(1, min(max_components, N // 2))
    gmm = BayesianGaussianMixture(n_components=k, weight_concentration_prior_type="dirichlet_process",
                                  covariance_type="full", max_iter=500, n_init=1, reg_covar=1e-4,
                                  random_state=seed, init_params="kmeans",
                                  weight_concentration_prior=concentration)
    gmm.fit(Z)
    proba = gmm.predict_proba(Z)
    share = np.bincount(proba.argmax(axis=1), minlength=k) / N
    kept = np.flatnonzero(share >= min_weight)
    if not kept.size:
        kept = np.array([int(share.argmax())])
    hard = kept[proba[:, kept].argmax(axis=1)]
    order = sorted(kept.tolist(), key=lambda c: float(tau[hard == c].mean()))
    relabel = {c: i for i, c in enumerate(order)}
    labels = np.array([relabel[c] for c in hard.tolist()], dtype=np.int64)
    centres = np.array([gmm.means_[c] * scale + mean for c in order])
    weights = np.bincount(labels, minlength=len(order)) / N
    return labels, centres, weights


def context_curves(runs: list[Run], schedule: Schedule, target: str,
                   channels: tuple[str, ...] = TEMPERATURES, every: int = int(FS) // 4,
                   max_components: int = 5, min_weight: float = 0.05, min_samples: int = 10,
                   nu: float = 4.0, n_iter: int = 3000, burn: int = 500, thin: int = 2,
                   seed: int = 0, concentration: float | None = None) -> list[OCContext]:
    """The contextual characteristic curve of every OC the runs reach (in schedule order).

    runs: recorded runs (``node.mcap.read_runs``) holding the switch, the target and
    ``channels``; the plateau samples of each OC (the OC detector's steady phase, as training
    cuts them) are taken every ``every`` samples (default 10: 4 Hz, which keeps the mixture fast;
    40, 1 Hz, makes the samples nearly independent for the sampler, and suits full-length
    plateaus). OCs with fewer than ``min_samples`` are
    left out. The mixture: ``cluster_temperatures`` (max_components, min_weight,
    concentration); per cluster ``gibbs_student_t`` (nu,
    n_iter, burn, thin) on its amplitudes, the chains seeded from ``seed`` (reproducible).
    A missing channel is a ValueError naming it.
    """
    out = []
    rng = np.random.default_rng(seed)
    for oc, d in _plateau_samples(runs, schedule, target, tuple(channels), every).items():
        if d["y"].size < min_samples:
            log.debug("%s: %d plateau samples, too few for a contextual curve",
                      schedule.names[oc], d["y"].size)
            continue
        labels, centres, weights = cluster_temperatures(d["X"], d["tau"], max_components, min_weight, seed,
                                                        concentration)
        posts = [gibbs_student_t(d["y"][labels == c], nu, None, n_iter, burn, thin, rng)
                 for c in range(len(weights))]
        out.append(OCContext(schedule.names[oc], oc, tuple(channels), d["run"].astype(np.int64), d["t"],
                             d["elapsed"], d["tau"], d["speed"], d["y"], d["X"], labels, centres,
                             weights, posts, target))
    return out


def out_of_order(ctx: OCContext) -> float:
    """How far the clusters are from following one another in time: the fraction of samples
    off the longest non-decreasing subsequence of labels of their run (in time order).

    0 when, in every run, the samples of cluster 0 come first, then cluster 1's, and so on
    (figure 3.4 (b)); a label flickering at a border costs the flickering samples.

    >>> c = OCContext("OC3", 1, ("tA",), np.zeros(6, int), np.arange(6.0), *[np.zeros(6)] * 5,
    ...               np.array([0, 0, 1, 0, 1, 2]), np.zeros((3, 1)), np.ones(3) / 3, [])
    >>> round(out_of_order(c), 3)
    0.167
    """
    if ctx.labels.size == 0:
        return 0.0
    on = 0
    for r in np.unique(ctx.run).tolist():
        mine = ctx.run == r
        seq = ctx.labels[mine][np.argsort(ctx.t[mine], kind="stable")]
        on += _longest_non_decreasing(seq.tolist())
    return 1.0 - on / ctx.labels.size


def _longest_non_decreasing(seq: list[int]) -> int:
    import bisect
    tails: list[int] = []
    for x in seq:
        i = bisect.bisect_right(tails, x)
        if i == len(tails):
            tails.append(x)
        else:
            tails[i] = x
    return len(tails)
