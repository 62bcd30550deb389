"""Section 6.3's axially loaded beam (``harness.beam``, as ``python -m bench parametric`` builds
it): the plain defaults interpolate WDMD models at p = 0, 3, 4 to p = 2 within eps_td 1.5e-2,
choosing the modal scheme (the axial load is stiffness-like) by leave-one-sample-out."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from harness import beam as bm
from node.sysid import WDMD, ParametricROM, StateSpace, eps_td

SPEC = bm.BeamSpec(width=0.020, wall=0.010)  # the bench's beam: 20 x 20 mm steel, 1 m


def truth(p: float) -> StateSpace:
    return bm.discrete_model(replace(SPEC, axial=1000.0 * p), [30], [13, 22, 30])


def test_the_defaults_on_the_beam_at_p_2() -> None:
    u = bm.quadratic_chirp(SPEC.fs, 4.0, 0.0, 150.0)[:, None]
    rom = ParametricROM(WDMD(levels=8), n_pairs=4).fit([(truth(p).simulate(u), u) for p in (0.0, 3.0, 4.0)],
                                                       [0.0, 3.0, 4.0])
    assert not rom.fallback_ and rom.choice_.scheme == "modal", rom.validation_.summary()
    with np.errstate(all="ignore"):
        err = eps_td(truth(2.0).simulate(u), rom.at(2.0).model_.simulate(u))
    assert err <= 1.5e-2, err
