"""Section 6.4.2's pseudo-time pROM (node.sysid.pseudo_time): the carrier's round trip, a level
set by the parameter recovered between runs, the error paths."""

from __future__ import annotations

import numpy as np
import pytest

from node.sysid.pseudo_time import PseudoTimePROM, Run, demodulate, modulate, phase


def test_demodulation_returns_the_amplitude_at_a_varying_speed() -> None:
    K, up, cycles = 400, 8, 8
    k = np.arange(K)
    amp = 2.0 + np.sin(2 * np.pi * k / 150.0)  # slow against the carrier (one turn per sample)
    speed = 6000.0 + 1500.0 * np.sin(2 * np.pi * k / 300.0)
    angle = phase(speed, up, 6000.0, cycles)
    back = demodulate(modulate(amp, angle, up), angle, up)
    assert back.shape == (K,)
    assert np.max(np.abs(back - amp)) < 0.02 * amp.max()


def _run(p: float, seed: int = 0, K: int = 240, start: int = 60) -> Run:
    """A run whose amplitude decays at a rate set by p (1 + 2 p % per sample), 1 % noise, at a
    constant speed."""
    amp = 3.0 * np.exp(-0.01 * (1 + 2 * p) * np.arange(K))
    noise = 0.01 * np.random.default_rng(seed).standard_normal(K)
    return Run(amp + noise, np.full(K, 5000.0), start, np.array([p]))


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a ** 2)))


def test_a_decay_set_by_the_parameter_is_recovered_between_runs() -> None:
    model = PseudoTimePROM(up=4, delays=4, n_pairs=1, n_real=0).fit(
        [_run(p, i) for i, p in enumerate([0.0, 0.3, 0.6, 1.0])])
    assert model.rom_.params_.shape == (4, 1)
    for p in (0.15, 0.45, 0.8):
        truth = _run(p, 99).amplitude[60:] - 0.01 * np.random.default_rng(99).standard_normal(240)[60:]
        err = _rms(model.predict(_run(p, 99)) - truth)
        assert err < 0.02
        # the parameter matters: the model at another value is further off
        other = Run(_run(p, 99).amplitude, np.full(240, 5000.0), 60, np.array([1.0 - p]))
        assert _rms(model.predict(other) - truth) > 2 * err


def test_several_segments_of_one_run_make_one_library_sample() -> None:
    library = [[_run(p, i), _run(p, 10 + i)] for i, p in enumerate([0.0, 0.5, 1.0])]
    model = PseudoTimePROM(up=4, delays=4, n_pairs=1, n_real=0).fit(library)
    assert len(model.models_) == 3


def test_bad_libraries_are_refused_in_one_line() -> None:
    with pytest.raises(ValueError, match="at least 2"):
        PseudoTimePROM().fit([_run(0.0, 0)])
    still = Run(np.ones(100), np.zeros(100), 20, np.array([0.0]))
    with pytest.raises(ValueError, match="speed must be positive"):
        PseudoTimePROM().fit([still, still])


def test_driven_by_the_imbalance_force_the_amplitude_follows_a_speed_step() -> None:
    """The order as the response to the pseudo shaft's imbalance force, (speed / mean)^2 (1 + p):
    a speed step after the OC's start moves the amplitude with it, at the run's own parameter;
    driven by the speed (the text's input) the model has nothing at the carrier and its free run
    dies out."""
    def run(p: float, K: int = 400, start: int = 100) -> Run:
        speed = np.where(np.arange(K) < start + 20, 4500.0, 5000.0)
        return Run((1.0 + p) * (speed / 4800.0) ** 2, speed, start, np.array([p]))

    truth = run(0.25).amplitude[100:]
    err = {}
    for drive in ("force", "speed"):
        model = PseudoTimePROM(up=4, delays=4, n_pairs=1, n_real=0, drive=drive).fit(
            [run(p) for p in (0.0, 0.5, 1.0)])
        err[drive] = _rms(model.predict(run(0.25)) - truth) / truth.max()
    assert err["force"] < 0.04 and err["speed"] > 0.5, err
    with pytest.raises(ValueError, match="drive"):
        PseudoTimePROM(drive="rpm").fit([run(0.0), run(1.0)])
