"""Input forms (absolute, increments from the OC switch) and the ridge of the DMD fits."""

from __future__ import annotations

import numpy as np
import pytest

from node.models.kinds import model_from_arrays
from node.models.ocmodel import InputForm, Method, StateSpaceModel, Trajectory
from node.sysid.lstsq import truncated_lstsq


def test_ridge_is_the_tikhonov_solution_relative_to_the_largest_singular_value():
    rng = np.random.default_rng(0)
    R, T = rng.normal(size=(200, 6)), rng.normal(size=(200, 2))
    R[:, 5] = R[:, 4] + 1e-3 * rng.normal(size=200)  # a weakly determined direction
    s0 = np.linalg.svd(R, compute_uv=False)[0]
    for ridge in (1e-4, 1e-2):
        W, rank = truncated_lstsq(R, T, 1e-12, scale_columns=False, ridge=ridge)
        expect = np.linalg.solve(R.T @ R + ridge * s0**2 * np.eye(6), R.T @ T)
        np.testing.assert_allclose(W, expect, rtol=1e-8, atol=1e-12)
        assert rank == 6
    plain, _ = truncated_lstsq(R, T, 1e-12, scale_columns=False)
    assert np.linalg.norm(W) < np.linalg.norm(plain)  # shrinks
    np.testing.assert_array_equal(plain, truncated_lstsq(R, T, 1e-12, scale_columns=False, ridge=0.0)[0])
    with pytest.raises(ValueError, match="ridge"):
        truncated_lstsq(R, T, 1e-12, ridge=-1.0)


def _system(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """y[k+1] = 0.95 y[k] + 0.1 (u[k] - 3) + 0.02 v[k], from a level that differs per run."""
    rng = np.random.default_rng(seed)
    u = 3.0 + np.cumsum(rng.normal(0.0, 0.05, n))
    v = rng.normal(0.0, 1.0, n)
    y = np.zeros(n)
    y[0] = rng.uniform(-1, 1)
    for k in range(n - 1):
        y[k + 1] = 0.95 * y[k] + 0.1 * (u[k] - 3.0) + 0.02 * v[k]
    return y, np.column_stack([u, v])


@pytest.mark.parametrize("start", [0, 150])
def test_the_stepper_runs_the_increment_form_as_prediction_does(start):
    trajs = [Trajectory(*_system(600, s), start=150) for s in range(4)]
    m = StateSpaceModel.fit(Method.DELAY_DMD, {"delays": 2, "form": "inc", "ridge": 1e-6}, trajs)
    y, U = _system(600, 9)
    traj = Trajectory(y[150 - start:], U[150 - start:], start)
    batch = m.predict(traj)
    rt = m.runtime()
    rt.start(traj.y[:start], traj.U[:start])
    online = np.array([rt.step(u) for u in traj.seg_U])
    np.testing.assert_allclose(online, batch, rtol=1e-9, atol=1e-9)
    # the increment form does not depend on the inputs' absolute level
    shifted = Trajectory(traj.y, traj.U + np.array([100.0, 0.0]), start)
    np.testing.assert_allclose(m.predict(shifted), batch, atol=1e-9)
    # and a bundle stores it (the form is a parameter)
    again = model_from_arrays(m.method.value, m.params, m.arrays(), m.repaired)
    np.testing.assert_array_equal(again.predict(traj), batch)
    assert Trajectory(y, U, 10).in_form(InputForm.ABSOLUTE).U is U
