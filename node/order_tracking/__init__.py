"""Order tracking from a raw vibration signal and a shaft speed.

- :func:`cot_orders`: computed order tracking (angular resampling, block DFT).
- :func:`vkf_orders`: joint second-generation Vold-Kalman filter.
- :func:`tvdft_orders`: time-variant DFT (the kernel follows the order), one output a sample.
- :func:`rpm_from_tacho`, :func:`tacho_pulse_times`: speed from a tacho signal.

The trackers return an :class:`OrderTrack` with time-major arrays; amplitudes are
peak amplitudes of ``a*cos(p*theta - phi)`` and phases the contract's lag ``phi`` in
degrees, in [-180, 180), from the shaft angle integrated from the speed, zero at the
first sample (put it on the once-per-rev mark). Invalid input raises ValueError.
"""

from .angle import rpm_from_tacho, shaft_revolutions, tacho_pulse_times
from .cot import cot_orders
from .result import OrderTrack
from .tvdft import tvdft_orders
from .vkf import DEFAULT_BANDWIDTH_HZ, vkf_orders, weighting_factor

__all__ = [
    "DEFAULT_BANDWIDTH_HZ",
    "OrderTrack",
    "cot_orders",
    "rpm_from_tacho",
    "shaft_revolutions",
    "tacho_pulse_times",
    "tvdft_orders",
    "vkf_orders",
    "weighting_factor",
]
