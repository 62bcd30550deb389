"""Container for order-tracking output (time-major arrays)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OrderTrack:
    """Tracked orders: amplitude and phase per output instant and order.

    Attributes
    ----------
    times : (K_out,) float, seconds from the first input sample.
    amplitudes : (K_out, n_orders) float, peak amplitude of each order component,
        in the unit of the input signal: ``a*cos(p*theta + phi)`` gives ``a``.
    phases : (K_out, n_orders) float, radians in (-pi, pi]: ``phi`` above, with the
        shaft angle ``theta`` (rad) integrated from the speed, ``theta = 0`` at the
        first input sample.
    orders : (n_orders,) float, the tracked orders (multiples of shaft speed).
    rpm : (K_out,) or (K_out, n_orders) float, reference speed(s) at ``times`` (rev/min).
    method : "cot", "vkf" or "tvdft".
    """

    times: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    orders: np.ndarray
    rpm: np.ndarray
    method: str

    @property
    def complex_amplitudes(self) -> np.ndarray:
        """(K_out, n_orders) complex ``a * exp(i*phi)``."""
        return self.amplitudes * np.exp(1j * self.phases)
