"""The curve fit as a sum of per-run parts (issue 17 item 1): the same models as a direct fit.

``CurveModel.fit`` is ``from_parts`` of each trajectory's ``part``; the CV makes every fold's
curve from the other runs' parts. Checked here against an independent reference fit (sample
loops, the node's scalar stepper, per-bin normal equations) on random runs with gaps, and the
CV's fold models against fitting each fold afresh, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from node.models.curve import DECAY_TAUS, FADE_SHARES, CurveModel, Variant, direction_codes
from node.models.kinds import fit_oc_model
from node.models.ocmodel import Method, Trajectory
from node.training.ocdata import OCData
from node.training.train import (
    CURVE_CANDIDATES,
    _predict_pairs,
    cross_validate_candidate,
    curve_model_inputs,
    oc_trajectories,
)

LOOKUPS = [c for c in CURVE_CANDIDATES if c["variant"] != "run"] + [
    {"variant": "fleet", "bin": 10.0, "window": 8, "deadband": 3.0, "min_count": 5},
    {"variant": "influence", "bin": 10.0, "anchor": 7, "ridge": 0.1},
]


def _runs(seed: int, n_runs: int, gaps: float) -> list[Trajectory]:
    """Runs of a speed ramp with noise, levels that follow the speed and the run's own unbalance,
    a fraction ``gaps`` of NaN speeds, levels and vectors, and a run or two without a long past."""
    rng = np.random.default_rng(seed)
    out = []
    for r in range(n_runs):
        k_hist = int(rng.integers(5, 3000)) if r % 3 else int(rng.integers(1, 60))
        k_seg = int(rng.integers(20, 400))
        lo, hi = rng.uniform(1000, 1500), rng.uniform(1600, 2600)
        speed = np.concatenate([np.full(k_hist, lo), np.linspace(lo, hi, k_seg)])
        speed += rng.normal(0, 6, speed.size)
        u = complex(*rng.normal(0, 1, 2))  # the run's unbalance
        z = (1 + speed / 1000) * (1 + 0.3 * u) * np.exp(-1j * speed / 700) + rng.normal(0, 0.02, speed.size)
        y = np.abs(z)
        for a in (speed, y):
            a[rng.random(a.size) < gaps] = np.nan
        z[rng.random(z.size) < gaps] = complex(np.nan, np.nan)
        out.append(Trajectory(y, speed[:, None], k_hist, z))
    return out


def _reference(params: dict, trajs: list[Trajectory]) -> CurveModel:
    """The curve by its definition, sample by sample (see ``CurveModel``'s attributes)."""
    variant = Variant(params["variant"])
    width, window = float(params.get("bin", 25.0)), int(params.get("window", 0))
    deadband, vector = float(params.get("deadband", 0.0)), variant.on_vector
    if variant is Variant.INFLUENCE:
        return _reference_influence(params, trajs)
    acc: dict[int, list[list]] = defaultdict(lambda: [[], [], []])
    for t in trajs:
        level = t.z if vector else t.y
        if variant.anchored:
            speed, ys = t.U[:, 0], level
            codes = direction_codes(speed[:0], speed, window, deadband)
        else:
            speed, ys = t.seg_U[:, 0], level[t.start:]
            past = t.U[:t.start, 0][-window:] if window else speed[:0]
            codes = direction_codes(past, speed, window, deadband)
        for x, v, c in zip(speed.tolist(), ys.tolist(), codes.tolist()):
            if math.isfinite(x) and np.isfinite(v):
                acc[math.floor(x / width)][c].append(v)
    bins = sorted(acc)
    means = np.zeros((3, len(bins)), complex if vector else float)
    for b, key in enumerate(bins):
        every = [v for vs in acc[key] for v in vs]
        for c in range(3):
            mine = acc[key][c]
            vals = mine if len(mine) >= max(1, int(params.get("min_count", 1))) else every
            mean = complex(math.fsum(np.real(vals)), math.fsum(np.imag(vals))) / len(vals)
            means[c, b] = mean if vector else mean.real
    centres = (np.array(bins) + 0.5) * width
    plain = CurveModel(dict(params), centres, means)
    if not variant.anchored:
        return plain
    rows, targets = [], []
    for t in trajs:  # the node's own scalar stepper gives the curve and the anchor
        level = t.z if vector else t.y
        rt = plain.runtime()
        rt.start(level[:t.start], t.U[:t.start])
        if rt.anchor is None:
            continue
        c = np.array([rt.step_speed(x) for x in t.seg_U[:, 0].tolist()], complex)
        c = c if vector else c.real
        y_sw, c_sw = rt.anchor
        rows.append(np.column_stack([c * (y_sw / c_sw - 1), np.full(c.size, y_sw - c_sw)]))
        targets.append(level[t.start:] - c)
    if not rows:
        return CurveModel(dict(params), centres, means, np.zeros(2))
    weights, decay = _reference_fade(rows, targets, True, bool(params.get("fade")))
    return CurveModel(dict(params), centres, means, weights, decay=decay)


def _reference_fade(rows: list[np.ndarray], targets: list[np.ndarray], fit_weights: bool, fade: bool
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The anchor's weights and fade by their definition (``CurveModel.decay``): each run's
    samples k = 0, 1, ... since the switch; the term's share 1 (held), or alpha + (1 - alpha)
    exp(-k / (tau FS)) for each alpha and tau of the grids; each share scored by its
    leave-one-run-out squared error (each run predicted with the weights, or a fade's scale,
    least squares on the others' samples; held without ``fit_weights``: weight 1); a fade taken
    when at least 3 runs and 1 % below the held one's, the lowest; then the weights over all."""
    ids = [np.full(len(t), i) for i, t in enumerate(targets)]
    since = [np.arange(len(t), dtype=float) for t in targets]
    X, r, k, g = np.vstack(rows), np.concatenate(targets), np.concatenate(since), np.concatenate(ids)
    ok = np.isfinite(r) & np.isfinite(X).all(axis=1)
    X, r, k, g = X[ok], r[ok], k[ok], g[ok]
    if np.iscomplexobj(X) or np.iscomplexobj(r):
        X, r = np.vstack([X.real, X.imag]), np.concatenate([r.real, r.imag])
        k, g = np.tile(k, 2), np.tile(g, 2)
    n, m = X.shape
    if n <= m + 3:
        return (np.zeros(m) if fit_weights else np.ones(m)), np.array([1.0, 0.0, 1.0])

    def loo(Xs: np.ndarray, fitted: bool) -> float:
        total = 0.0
        for run in np.unique(g):
            out = g == run
            w = np.linalg.lstsq(Xs[~out], r[~out], rcond=None)[0] if fitted else np.ones(m)
            total += float(np.sum((r[out] - Xs[out] @ w) ** 2))
        return total

    best = None
    if fade and len(np.unique(g)) >= 3:
        held = loo(X, fit_weights)
        for tau in DECAY_TAUS:
            for alpha in FADE_SHARES:
                s = alpha + (1 - alpha) * np.exp(-k / (tau * 40.0))
                sse = loo(X * s[:, None], True)
                if sse < 0.99 * held and (best is None or sse < best[0]):
                    best = (sse, s, (alpha, 1 - alpha, math.exp(-1 / (tau * 40.0))))
    if best is None:
        w = np.linalg.lstsq(X, r, rcond=None)[0] if fit_weights else np.ones(m)
        return w, np.array([1.0, 0.0, 1.0])
    _, s, (alpha, beta, ratio) = best
    w = np.linalg.lstsq(X * s[:, None], r, rcond=None)[0]
    if fit_weights:
        return w, np.array([alpha, beta, ratio])
    return np.ones(m), np.array([w[0] * alpha, w[0] * beta, ratio])


def _reference_influence(params: dict, trajs: list[Trajectory]) -> CurveModel:
    """Per bin, b and g minimising sum |z - b - g x|^2 + lam |g|^2 (x: the run's anchor about
    the runs' mean, lam = ridge x n x mean |x|^2), by the 2 x 2 normal equations."""
    width, ridge = float(params["bin"]), float(params.get("ridge", 1e-3))
    samples = []
    for t in trajs:
        rt = CurveModel(dict(params), np.zeros(1), np.zeros((3, 1)), gains=np.zeros(1)).runtime()
        rt.start(t.z[:t.start], t.U[:t.start])
        a = rt.anchor[0] if rt.anchor is not None else None
        samples += [(x, v, a) for x, v in zip(t.U[:, 0].tolist(), t.z.tolist())
                    if math.isfinite(x) and np.isfinite(v)]
    known = [s for s in samples if s[2] is not None]
    samples = known or [(x, v, 0j) for x, v, _ in samples]
    a_mean = np.mean([s[2] for s in samples]) if known else 0j
    if len({s[2] for s in samples}) == 1:  # one anchor: x is 0, the gains 0 (not rounding's ratio)
        a_mean = samples[0][2]
    mean_x2 = np.mean([abs(s[2] - a_mean) ** 2 for s in samples])
    by_bin: dict[int, list] = defaultdict(list)
    for x, v, a in samples:
        by_bin[math.floor(x / width)].append((a - a_mean, v))
    bins = sorted(by_bin)
    b, g = np.zeros(len(bins), complex), np.zeros(len(bins), complex)
    for k, key in enumerate(bins):
        xs, zs = np.array([p[0] for p in by_bin[key]]), np.array([p[1] for p in by_bin[key]])
        n, lam = xs.size, ridge * xs.size * mean_x2
        A = np.array([[n, xs.sum()], [np.conj(xs).sum(), np.sum(np.abs(xs) ** 2) + lam + 1e-300]])
        b[k], g[k] = np.linalg.solve(A, [zs.sum(), np.sum(np.conj(xs) * zs)])
    model = CurveModel(dict(params), (np.array(bins) + 0.5) * width, np.tile(b, (3, 1)), gains=g,
                       anchor_mean=a_mean)
    rows, targets = [], []
    for t in trajs:  # the anchor's term by the node's scalar stepper, held
        rt = model.runtime()
        rt.start(t.z[:t.start], t.U[:t.start])
        if rt.anchor is None:
            continue
        y_sw, mean = rt.anchor
        c = np.array([rt._lookup(x, 0) if math.isfinite(x) else np.nan for x in t.seg_U[:, 0].tolist()])
        gain = np.array([rt._lookup(x, 3) if math.isfinite(x) else np.nan for x in t.seg_U[:, 0].tolist()])
        rows.append((gain * (y_sw - mean))[:, None])
        targets.append(t.z[t.start:] - c)
    if rows:
        _, decay = _reference_fade(rows, targets, False, bool(params.get("fade")))
        model = dataclasses.replace(model, decay=decay)
    return model


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_runs=st.integers(1, 5), gaps=st.sampled_from([0.0, 0.01, 0.2]))
def test_the_fit_from_parts_is_the_curve_by_its_definition(seed: int, n_runs: int, gaps: float) -> None:
    trajs = _runs(seed, n_runs, gaps)
    for params in LOOKUPS:
        m, ref = CurveModel.fit(Method.CURVE, params, trajs), _reference(params, trajs)
        np.testing.assert_array_equal(m.centres, ref.centres)
        np.testing.assert_allclose(m.means, ref.means, rtol=1e-9, atol=1e-12, err_msg=str(params))
        np.testing.assert_allclose(m.weights, ref.weights, rtol=1e-7, atol=1e-10, err_msg=str(params))
        np.testing.assert_allclose(m.gains, ref.gains, rtol=1e-7, atol=1e-10, err_msg=str(params))
        assert abs(m.anchor_mean - ref.anchor_mean) <= 1e-12 * (1 + abs(ref.anchor_mean))
        np.testing.assert_allclose(m.decay, ref.decay, rtol=1e-12, err_msg=str(params))


def test_a_part_is_the_same_whatever_the_other_runs_and_the_fit_of_parts_is_the_fit() -> None:
    """Every fold's model from the parts, bit for bit the model fitted on its runs afresh."""
    trajs = _runs(7, 5, 0.01)
    for params in LOOKUPS:
        parts = [CurveModel.part(params, t) for t in trajs]
        for out in range(len(trajs)):
            rows = [i for i in range(len(trajs)) if i != out]
            a = CurveModel.from_parts(params, [parts[i] for i in rows])
            b = CurveModel.fit(Method.CURVE, params, [trajs[i] for i in rows])
            for key, arr in a.arrays().items():
                np.testing.assert_array_equal(arr, b.arrays()[key])


def test_the_cv_of_a_curve_gives_the_pairs_of_fitting_every_fold_afresh() -> None:
    trajs = _runs(11, 6, 0.0)
    d = OCData("OC1", "yB", ["nB"], list(range(6)), [t.y for t in trajs], [t.U for t in trajs],
               [t.start for t in trajs], [0] * 6, switch="nB", curves=LOOKUPS, z=[t.z for t in trajs])
    folds = list(range(6))
    for params in LOOKUPS:
        inputs = curve_model_inputs(d, params)
        assert inputs == ["nB"]
        score, pairs = cross_validate_candidate(d, folds, Method.CURVE, params, dict.fromkeys(folds, inputs))
        expected = []
        for f in folds:
            m = fit_oc_model(Method.CURVE, params, oc_trajectories(d, [i for i in folds if i != f], inputs))
            expected += _predict_pairs(m, oc_trajectories(d, [f], inputs))
        assert len(pairs) == len(expected) and math.isfinite(score)
        for (_, p), (_, p2) in zip(pairs, expected):
            np.testing.assert_array_equal(p, p2)
