"""Container for order-tracking output (time-major arrays), and the phase convention.

Every tracker returns the contract's phase (``docs/contract.md`` section 1, the ``<order>_ph``
channels): the lag of the order from the shaft's angle zero, in degrees, in [-180, 180)
(``node.contract.vector.order_lags`` of the tracker's complex amplitude ``a exp(-j lag)``).
``a*cos(p*theta - phi)`` gives the phase ``phi``: a signal peaking after the angle's zero lags
it. The angle's zero is the first input sample (``shaft_revolutions``), so with the first
sample on the once-per-rev mark the phase is the contract's lag from that mark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.contract.vector import order_vectors


@dataclass(frozen=True)
class OrderTrack:
    """Tracked orders: amplitude and phase per output instant and order.

    Attributes
    ----------
    times : (K_out,) float, seconds from the first input sample.
    amplitudes : (K_out, n_orders) float, peak amplitude of each order component,
        in the unit of the input signal: ``a*cos(p*theta - phi)`` gives ``a``.
    phases : (K_out, n_orders) float, degrees in [-180, 180): the lag ``phi`` above (the
        contract's phase, see the module), with the shaft angle ``theta`` (rad) integrated
        from the speed, ``theta = 0`` at the first input sample.
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
        """(K_out, n_orders) complex ``a * exp(-j*phi)``, the contract's 1x vector
        (``node.contract.vector.order_vectors``)."""
        return order_vectors(self.amplitudes, self.phases)
