"""Identification methods: ioDMD, Delay-DMD and WDMD, one state-space type, metrics,
parametric models (pole-residue interpolation).

    from node.sysid import IODMD, DelayDMD, WDMD
    m = WDMD(levels=4, wavelet="haar", rcond=1e-12).fit(Y, U)
    Yhat = m.simulate(U2, history=(Y1, U1))

Arrays are time-major (samples, channels).
"""

from node.sysid.base import Estimator, LinearDMD
from node.sysid.delay_dmd import DelayDMD, delay_embed
from node.sysid.iodmd import IODMD
from node.sysid.metrics import eps_fd, eps_td, mac, pooled_eps
from node.sysid.observer import estimate_state
from node.sysid.parametric import ParametricModel, ParametricROM
from node.sysid.statespace import PoleResidue, StateSpace
from node.sysid.wavelets import CausalMODWT, causal_modwt, modwt_mra
from node.sysid.wdmd import WDMD, Components

__all__ = [
    "IODMD", "DelayDMD", "WDMD", "LinearDMD", "Estimator", "Components", "StateSpace",
    "PoleResidue", "ParametricROM", "ParametricModel", "CausalMODWT", "causal_modwt", "modwt_mra",
    "delay_embed",
    "eps_td", "eps_fd", "mac", "pooled_eps", "estimate_state",
]
