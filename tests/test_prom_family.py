"""The generated family of ``harness.prom_family`` on a small seeded sample (the full family:
``python -m bench prom-family``): the default ParametricROM judged at an interior parameter
against the nearest sample's model and a WDMD fitted there, and every fallback warned."""

from __future__ import annotations

import pytest

from harness import prom_family as pf

# seeds of all three classes and noise levels whose cases run in a few seconds each (the
# veering blocks' joint fits of some 3-4 DOF cases take a minute); 34 and 39 fall back
SEEDS = [17, 34, 36, 38, 39]


@pytest.fixture(scope="module")
def results() -> list[pf.Result]:
    return pf.run(SEEDS)


def test_the_sample_covers_every_class(results) -> None:
    assert {r.case.kind for r in results} == set(pf.KINDS)
    assert {r.case.noise for r in results} == set(pf.NOISES)
    for r in results:
        assert r.case.samples[0] < r.case.target < r.case.samples[-1]
        assert 3 <= len(r.case.samples) <= 5 and 2 <= r.case.n <= 4


def test_every_fallback_is_warned(results) -> None:
    silent = [r.case.label() for r in results if not r.honest]
    assert not silent, silent
    assert any(r.fell_back for r in results)  # the sample holds a fallback
