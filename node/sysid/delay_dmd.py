"""Delay-DMD: ioDMD on time-delay embedded outputs (eq. 3.21-3.25, section 4.4.4)."""

from __future__ import annotations

import numpy as np

from node.sysid.base import LinearDMD


def delay_embed(Y: np.ndarray, delays: int, lag: int = 1, start: int = 0) -> np.ndarray:
    """Causal delay embedding: row k = [y[k-start], y[k-start-lag], ..., (``delays`` blocks)].

    Y (K, p) -> (K, p * delays), block-major (all channels of one delay together).
    Samples before the start are taken equal to Y[0] (edge extension).
    """
    K, p = Y.shape
    if delays == 0:
        return np.zeros((K, 0))
    span = start + (delays - 1) * lag
    ext = np.concatenate([np.repeat(Y[:1], span, axis=0), Y], axis=0)
    return np.hstack([ext[span - start - d * lag: span - start - d * lag + K] for d in range(delays)])


class DelayDMD(LinearDMD):
    """Delay-DMD with ``delays`` output blocks (tau) spaced by ``lag`` (delta).

    State: [y[k], y[k-lag], ..., y[k-(delays-1) lag]] (p * delays), as in the
    dissertation; with ``input_delays`` > 0 the past inputs
    [u[k-1], ..., u[k-input_delays]] join the state, which makes the model an
    exact realisation of any LTI system of order <= p * delays.
    Other arguments as :class:`LinearDMD`.

    y[k+1] = 1.5 y[k] - 0.7 y[k-1] + u[k] has the state [y[k], y[k-1]]: two
    delays recover its poles (modulus sqrt(0.7)) and its free run:

    >>> from node.sysid import eps_td
    >>> u = np.random.default_rng(0).normal(size=(400, 1))
    >>> y = np.zeros((400, 1))
    >>> for k in range(1, 399):
    ...     y[k + 1] = 1.5 * y[k] - 0.7 * y[k - 1] + u[k]
    >>> m = DelayDMD(delays=2, warmup=1).fit(y, u)
    >>> np.round(np.abs(m.model_.poles()), 4)
    array([0.8367, 0.8367])
    >>> bool(eps_td(y[300:], m.simulate(u[300:], history=(y[:300], u[:300]))) < 1e-8)
    True
    """

    def __init__(self, delays: int = 10, lag: int = 1, input_delays: int = 0,
                 rcond: float = 1e-10, rank: int | None = None, estimator: str = "oe",
                 dt: float = 1.0, warmup: int = 0, seed_window: int | None = None,
                 ridge: float = 0.0) -> None:
        super().__init__(rcond=rcond, rank=rank, estimator=estimator, dt=dt, warmup=warmup,
                         seed_window=seed_window, ridge=ridge)
        self.delays = delays
        self.lag = lag
        self.input_delays = input_delays

    def _check_params(self):
        for name, low in (("delays", 1), ("lag", 1), ("input_delays", 0)):
            v = getattr(self, name)
            if int(v) != v or v < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
        return super()._check_params()

    def memory(self) -> int:
        return max((int(self.delays) - 1) * int(self.lag), int(self.input_delays))

    def _lift(self, Y: np.ndarray, U: np.ndarray) -> np.ndarray:
        Zy = delay_embed(Y, int(self.delays), int(self.lag))
        if not self.input_delays or U.shape[1] == 0:
            return Zy
        return np.hstack([Zy, delay_embed(U, int(self.input_delays), 1, start=1)])
