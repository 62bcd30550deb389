"""Contextual characteristic curves (section 3.4): the Gibbs sampler against its closed form,
its robustness to outliers, and the mixture's clusters following one another in time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from node.contract.schedule import load_schedule
from node.training.context import (
    NIGPrior,
    batch_means_se,
    context_curves,
    gibbs_student_t,
    nig_posterior,
    out_of_order,
)
from node.training.runs import read_runs

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "recordings" / "engine1_runs.mcap"


@pytest.mark.parametrize("n, prior", [
    (30, NIGPrior(m0=4.0, k0=2.0, a0=3.0, b0=0.5)),  # an informative prior pulls the mean
    (200, NIGPrior(m0=0.0, k0=0.01, a0=1.0, b0=0.01)),  # a weak one: the data speak
])
def test_gibbs_with_normal_likelihood_matches_the_conjugate_posterior(n, prior):
    """nu very large: lambda_i -> 1, the normal likelihood, whose posterior under the
    normal-inverse-gamma prior is known in closed form. Both posterior means within 4 Monte
    Carlo standard errors (batch means over the chain)."""
    y = np.random.default_rng(11).normal(5.0, 0.7, n)
    post = gibbs_student_t(y, nu=1e8, prior=prior, n_iter=12000, burn=1000, thin=1, seed=3)
    mu_exact, var_exact = nig_posterior(y, prior)
    var = post.sigma ** 2
    se_mu, se_var = batch_means_se(post.mu), batch_means_se(var)
    assert 0 < se_mu < 0.02 and 0 < se_var < 0.05
    assert abs(post.mu.mean() - mu_exact) < 4 * se_mu
    assert abs(var.mean() - var_exact) < 4 * se_var
    # nu = inf is the normal likelihood exactly
    exact = gibbs_student_t(y, nu=np.inf, prior=prior, n_iter=12000, burn=1000, thin=1, seed=4)
    assert abs(exact.mu.mean() - mu_exact) < 4 * batch_means_se(exact.mu)


def test_student_t_posterior_stays_with_the_bulk_when_outliers_come():
    rng = np.random.default_rng(5)
    bulk = rng.normal(2.0, 0.3, 120)
    y = np.concatenate([bulk, [9.0, 10.0, 11.0, 12.0, 9.5, 10.5]])  # 5 % gross outliers
    robust = gibbs_student_t(y, nu=4.0, seed=1)
    normal = gibbs_student_t(y, nu=np.inf, seed=1)
    assert abs(robust.mu.mean() - bulk.mean()) < 0.05  # near the bulk
    assert normal.mu.mean() - bulk.mean() > 0.3  # the normal mean is dragged towards them
    assert robust.sigma.mean() < 0.5 < normal.sigma.mean()
    # seeded: the same chain again
    np.testing.assert_array_equal(robust.mu, gibbs_student_t(y, nu=4.0, seed=1).mu)


def test_clusters_follow_one_another_in_time_within_an_oc():
    """On the simulator's runs (the committed recording), per OC: in every run the samples of
    the earlier cluster come before those of the later one (figure 3.4 (b)): at most 5 % of an
    OC's samples lie off the longest time-ordered label sequence of their run, and the runs
    do pass through several clusters within one plateau (the order is no accident of one
    cluster per run)."""
    runs = read_runs(str(RUNS))
    schedule = load_schedule(ROOT / "recordings" / "engine1_runs.schedule.toml")
    ctx = context_curves(runs, schedule, "yB", n_iter=600, burn=100, thin=1)
    assert [c.name for c in ctx] == list(schedule.names)
    for c in ctx:
        assert out_of_order(c) <= 0.05, c.name
        assert c.labels.min() == 0 and c.labels.max() == c.n_clusters - 1
        assert np.isclose(c.weights.sum(), 1.0) and c.centres.shape == (c.n_clusters, 3)
        mean_tau = [c.tau[c.labels == k].mean() for k in range(c.n_clusters)]
        assert mean_tau == sorted(mean_tau)  # ordered by their time in the plateau
        for p in c.posteriors:
            assert p.mu.shape == (500,) and np.isfinite(p.mu).all() and (p.sigma > 0).all()
    several = [c.name for c in ctx if any(len(set(c.labels[c.run == r].tolist())) >= 2
                                          for r in range(len(runs)))]
    assert len(several) >= len(ctx) // 2, several
    # the figures of panel I draw them (3 panels per OC; mu and sigma per OC)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from replay.views.context_plots import fig_context_clusters, fig_context_timeline, fig_context_violins
    fig = fig_context_clusters(ctx[:2])
    assert len(fig.axes) == 6 and fig.axes[0].get_title(loc="left").startswith("OC2a")
    FigureCanvasAgg(fig).draw()
    fig = fig_context_timeline(ctx)
    assert len(fig.axes[0].collections) >= sum(len(np.unique(c.run)) for c in ctx)  # a bar per stretch
    FigureCanvasAgg(fig).draw()
    fig = fig_context_violins(ctx)
    assert sum(bool(ax.collections) for ax in fig.axes) == 2 * len(ctx)
    FigureCanvasAgg(fig).draw()
