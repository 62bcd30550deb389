"""Transient analysis (node.runtime.transient): known single- and two-mode responses recovered
from ramps, with and without the order tracker's lag and noise; the simulator's phase rolls
through its criticals and nowhere else."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from node.runtime.transient import (
    af_of_zeta,
    analyse,
    bode,
    find_transitions,
    lagged,
    slow_roll_vector,
    untracked,
    zeta_from_af,
)

FS = 40.0


def _response(speed: np.ndarray, modes: list[tuple[float, float, float]], u: complex = 1e-3,
              bow: complex = 0.0) -> np.ndarray:
    """Velocity 1x vector (K,) of a rotor with modes [(Nc rpm, zeta, participation)]:
    speed * sum phi (r^2 u + bow) / (1 - r^2 + 2j zeta r)."""
    z = sum(phi * ((speed / nc) ** 2 * u + bow) / (1 - (speed / nc) ** 2 + 2j * zeta * speed / nc)
            for nc, zeta, phi in modes)
    return speed * z


def _ramp(lo: float, hi: float, rate: float, settle_s: float = 5.0) -> np.ndarray:
    """A ramp lo -> hi (rate > 0) or hi -> lo (rate < 0) at |rate| rpm/s, held settle_s at each end."""
    n = int(round(abs(hi - lo) / abs(rate) * FS))
    ramp = np.linspace(lo, hi, n) if rate > 0 else np.linspace(hi, lo, n)
    hold = int(settle_s * FS)
    return np.concatenate([np.full(hold, ramp[0]), ramp, np.full(hold, ramp[-1])])


def _tracked(v: np.ndarray, tau: float) -> np.ndarray:
    """The vector through the tracker's first-order lag (real and imaginary parts alike)."""
    return lagged(v.real, tau) + 1j * lagged(v.imag, tau)


def _amp_phase(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.abs(v), -np.degrees(np.angle(v))


@pytest.mark.parametrize("zeta", [0.03, 0.06, 0.1])
def test_single_mode_recovered_noise_free(zeta: float) -> None:
    speed = _ramp(3000.0, 9000.0, 100.0)
    v = _response(speed, [(6000.0, zeta, 1.0)])
    out = analyse(speed, *_amp_phase(v))
    (c,) = out.criticals
    assert out.direction == "up"
    assert c.speed == pytest.approx(6000.0, rel=2e-4)
    assert c.af_phase == pytest.approx(1 / (2 * zeta), rel=0.01)  # the modal fit: exact
    # API half-power on the fitted mode's own response: a few % below 1 / (2 zeta), exactly
    assert c.af == pytest.approx(af_of_zeta(zeta), rel=0.01) and c.zeta == pytest.approx(zeta, rel=0.01)
    assert c.af_hp is not None and c.af_hp == pytest.approx(1 / (2 * zeta), rel=0.06)  # the measured peak's
    assert c.af_method == "modal fit" and c.phase_change is not None and c.phase_change > 120
    # the amplitude alone: the half-power method, the critical from the peak's offset
    (a,) = analyse(speed, np.abs(v)).criticals
    assert a.speed == pytest.approx(6000.0, rel=2e-3) and a.speed_phase is None
    assert a.af == pytest.approx(1 / (2 * zeta), rel=0.06)


@pytest.mark.parametrize("rate", [120.0, -120.0])
def test_tracker_lag_undone_and_its_shift_opposite_up_and_down(rate: float) -> None:
    tau, zeta = 1.0, 0.04
    speed = _ramp(5000.0, 11000.0, rate)
    v = _tracked(_response(speed, [(8000.0, zeta, 1.0)]), tau)
    (c,) = analyse(speed, *_amp_phase(v), tracker_tau=tau).criticals
    assert c.speed == pytest.approx(8000.0, rel=5e-4)
    assert c.af_phase == pytest.approx(1 / (2 * zeta), rel=0.03)
    (raw,) = analyse(speed, *_amp_phase(v), tracker_tau=0.0).criticals
    # without the correction the peak trails the critical: high on a run-up, low on a coast-down
    shift = raw.speed_peak - c.speed_peak
    assert np.sign(shift) == np.sign(rate) and abs(shift) > 0.5 * abs(rate) * tau


def test_two_modes_recovered_separated_and_close() -> None:
    speed = _ramp(2500.0, 9800.0, -90.0)  # a coast-down
    modes = [(4400.0, 0.07, 0.8), (8100.0, 0.045, -1.0), (9300.0, 0.03, 0.5)]
    out = analyse(speed, *_amp_phase(_response(speed, modes)))
    assert out.direction == "down"
    got = sorted(out.criticals, key=lambda c: c.speed)
    assert len(got) == 3
    for c, (nc, zeta, _) in zip(got, modes, strict=True):
        assert c.speed == pytest.approx(nc, rel=2e-3)
        assert c.af_phase == pytest.approx(1 / (2 * zeta), rel=0.05)
        assert c.af == pytest.approx(1 / (2 * zeta), rel=0.2)


def _criticals_of_two_modes(rel: float, seed: int) -> list[tuple[float, float]]:
    """The criticals (speed, AF) of the three-mode coast-down above, its inputs scaled by
    1 + rel * N(0, 1) sample by sample."""
    speed = _ramp(2500.0, 9800.0, -90.0)
    modes = [(4400.0, 0.07, 0.8), (8100.0, 0.045, -1.0), (9300.0, 0.03, 0.5)]
    amp, ph = _amp_phase(_response(speed, modes))
    rng = np.random.default_rng(seed)
    jig = [1 + rel * rng.standard_normal(len(speed)) for _ in range(3)]
    out = analyse(speed * jig[0], amp * jig[1], ph * jig[2])
    return [(c.speed, c.af) for c in out.criticals]


@pytest.mark.parametrize("seed", range(4))
def test_criticals_do_not_rest_on_the_last_bits(seed: int) -> None:
    """Inputs perturbed by 1e-12 relative: the same criticals (no decision on a threshold that
    rounding crosses)."""
    base = _criticals_of_two_modes(0.0, 0)
    got = _criticals_of_two_modes(1e-12, seed)
    assert len(got) == len(base) == 3
    for (s, af), (s0, af0) in zip(got, base, strict=True):
        assert s == pytest.approx(s0, rel=1e-6)
        assert af == pytest.approx(af0, rel=1e-4)


def test_criticals_do_not_depend_on_the_blas_kernels() -> None:
    """The same analysis with OpenBLAS's oldest x86-64 kernels (as on another processor)
    finds the same criticals."""
    import os
    import subprocess
    import sys

    code = ("import json, sys; sys.path.insert(0, 'tests'); import test_transient as t; "
            "print(json.dumps(t._criticals_of_two_modes(0.0, 0)))")
    env = {**os.environ, "OPENBLAS_CORETYPE": "Prescott"}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parent.parent, timeout=300, check=True)
    other = json.loads(run.stdout.strip().splitlines()[-1])
    here = _criticals_of_two_modes(0.0, 0)
    assert len(other) == len(here) == 3
    for (s, af), (s0, af0) in zip(other, here, strict=True):
        assert s == pytest.approx(s0, rel=1e-5)
        assert af == pytest.approx(af0, rel=1e-3)


def test_noisy_ramp_within_the_targets() -> None:
    """The simulator's sensor noise (amplitude sigma 0.03 + 2 %, phase the same over the
    amplitude, 0.01 mm/s and 0.1 degree resolution) on a tracked two-mode run-up."""
    rng = np.random.default_rng(3)
    speed = _ramp(3000.0, 9800.0, 80.0)
    modes = [(5000.0, 0.06, 0.8), (8300.0, 0.04, -1.0)]
    v = _tracked(_response(speed, modes, u=1.5e-3), 1.0)
    amp, ph = _amp_phase(v)
    sigma = 0.03 + 0.02 * amp
    amp_m = np.round(np.clip(amp + sigma * rng.standard_normal(len(amp)), 0, None), 2)
    ph_m = np.round(ph + np.degrees(sigma / amp) * rng.standard_normal(len(amp)), 1)
    speed_m = np.round(speed + (1 + 3e-4 * speed) * rng.standard_normal(len(speed)))
    amp_m[rng.random(len(amp)) < 0.01] = np.nan  # dropouts
    out = analyse(speed_m, amp_m, ph_m, tracker_tau=1.0, min_amplitude=0.2)
    got = sorted(out.criticals, key=lambda c: c.speed)
    assert len(got) == 2
    for c, (nc, zeta, _) in zip(got, modes, strict=True):
        assert c.speed == pytest.approx(nc, rel=0.005)
        assert c.af == pytest.approx(1 / (2 * zeta), rel=0.2)
        assert c.af_phase == pytest.approx(1 / (2 * zeta), rel=0.2)


@pytest.mark.parametrize("seed", range(10))
def test_weak_first_mode_on_the_flank_of_a_stronger_one(seed: int) -> None:
    """The simulator's LP rotor (its mass line and a weak, well-damped first mode, AF 5, on
    the flank of the second) on a decel at its rate, with its sensor noise: the first mode's
    noisy lag breaks up at the fine scale of the roll search; found at every seed within the
    bench's targets (1 %, 20 %)."""
    from simulator import rotor
    from simulator.campaign import phase_sigma
    from simulator.engine import LP_SHAFT

    rng = np.random.default_rng(seed)
    speed = _ramp(400.0, 1750.0, -53.0)
    k = len(speed)
    v = rotor.tracked(rotor.order(LP_SHAFT, speed, np.full(k, 15.0), np.full(k, 3e-3 * np.exp(1j)),
                                  np.zeros(k, dtype=complex)))
    amp, ph = _amp_phase(v)
    amp_m = np.round(np.clip(amp + (0.03 + 0.02 * amp) * rng.standard_normal(k), 0, None), 2)
    ph_m = np.round(ph + phase_sigma(amp) * rng.standard_normal(k), 1)
    ph_m[amp < 0.1] = np.nan  # the unit gives no phase below 0.1 mm/s
    speed_m = np.round(speed + (1 + 3e-4 * speed) * rng.standard_normal(k))
    out = analyse(speed_m, amp_m, ph_m, tracker_tau=1.0, min_amplitude=0.2)
    mode = LP_SHAFT.modes[0]
    (c,) = out.criticals
    assert c.speed == pytest.approx(mode.rpm, rel=0.01)
    assert c.af == pytest.approx(1 / (2 * mode.zeta), rel=0.2)


def test_a_mode_near_the_top_of_a_coast_down_counts_with_its_half_power_band_inside() -> None:
    """yB's 0.955 mode just below the top plateau: its half-power points lie inside the
    coast-down (API 684's need) but not 1.5 half-widths of margin; found, next to the 0.83
    one, within the bench's targets."""
    speed = _ramp(6500.0, 9800.0, -110.0)
    modes = [(8280.0, 0.044, -1.0), (9400.0, 0.03, 0.5)]
    v = _tracked(_response(speed, modes), 1.0)
    got = analyse(speed, *_amp_phase(v), tracker_tau=1.0).criticals
    assert len(got) == 2
    for c, (nc, zeta, _) in zip(got, modes, strict=True):
        assert c.speed == pytest.approx(nc, rel=0.01) and c.n2 < 9800.0
        assert c.af == pytest.approx(1 / (2 * zeta), rel=0.2)


def test_long_gap_leaves_no_outlier_after_the_lag_is_undone() -> None:
    """A dropout burst in a turning vector: the straight fill across it is no signal, so the
    samples whose derivative window reaches into it are left out (they were outliers)."""
    t = np.arange(0, 30, 1 / FS)
    u = np.exp(1j * 0.8 * t)
    y = _tracked(u, 1.0)
    y[400:440] = np.nan  # a 1 s burst: the vector turns 46 degrees meanwhile
    y[600] = np.nan  # an isolated dropout: filled, its neighbours kept
    got = untracked(y, 1.0)
    assert np.isnan(got[390:450]).all() and np.isfinite(got[599]) and np.isfinite(got[601])
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok][20:-20], u[ok][20:-20], atol=2e-2)


def test_flat_noise_has_no_critical() -> None:
    rng = np.random.default_rng(0)
    speed = _ramp(2000.0, 8000.0, 100.0)
    amp = 0.3 + 0.03 * rng.standard_normal(len(speed))
    phase = 40.0 + 5.0 * rng.standard_normal(len(speed))
    assert analyse(speed, amp, phase, min_amplitude=0.2).criticals == []
    assert analyse(speed, amp, min_amplitude=0.2).criticals == []


def test_slow_roll_vector_removes_a_runout() -> None:
    """A bowed rotor: at slow roll the 1x vector is the bow's (a runout, constant in
    displacement); less that vector the response is an unbalance response again."""
    speed = _ramp(200.0, 8000.0, 100.0)
    modes = [(5000.0, 0.05, 1.0)]
    v = _response(speed, modes, u=1e-3, bow=2e-3j)
    amp, ph = _amp_phase(v)
    sr = slow_roll_vector(speed, amp, ph, (200.0, 600.0))
    assert sr is not None and abs(sr - 2e-3j * (2 * np.pi / 60) * 0) >= 0  # a vector in response units
    b = bode(speed, amp, ph, slow_roll=sr)
    assert b.vector is not None and abs(b.vector[0]) < 0.02 * np.nanmax(np.abs(b.vector))
    (c,) = analyse(speed, amp, ph, slow_roll=sr).criticals
    assert c.speed == pytest.approx(5000.0, rel=2e-3)


def test_untracked_inverts_the_lag_and_bad_input() -> None:
    t = np.arange(0, 30, 1 / FS)
    u = np.exp(1j * 0.3 * t) * (1 + 0.5 * np.sin(0.2 * t))
    y = _tracked(u, 1.5)
    np.testing.assert_allclose(untracked(y, 1.5)[40:-40], u[40:-40], atol=1e-2)
    with pytest.raises(ValueError, match="same shape"):
        bode(np.ones(10), np.ones(9))
    with pytest.raises(ValueError, match="at least 3"):
        bode(np.full(5, np.nan), np.ones(5))
    assert zeta_from_af(9.9)[0] == pytest.approx(0.05, rel=0.01)


def test_find_transitions_of_a_run() -> None:
    rng = np.random.default_rng(1)
    speed = np.concatenate([_ramp(0.0, 2600.0, 130.0), np.full(600, 2600.0), _ramp(2600.0, 6500.0, 90.0),
                            np.full(800, 6500.0), _ramp(3000.0, 6500.0, -100.0)])
    speed = speed + rng.standard_normal(len(speed))
    speed[500:520] = np.nan  # a dropout burst inside the first ramp
    got = find_transitions(speed)
    assert [g.direction for g in got] == ["up", "up", "down"]
    assert [round(g.to_speed, -2) for g in got] == [2600.0, 6500.0, 3000.0]
    assert all(g.stop <= h.start for g, h in zip(got, got[1:], strict=False))
    assert find_transitions(np.full(2000, 5000.0)) == []


# --- the simulator -----------------------------------------------------------------------------


@pytest.mark.parametrize("metal", [15.0, 300.0])
def test_simulator_phase_rolls_through_each_critical_only(metal: float) -> None:
    """The steady 1x vector of every shaft (nominal modes, no bow): through each mode's band
    (-/+ 3 zeta, up to the middle between two criticals) the lag grows by most of 180 degrees
    and the amplitude peaks in the half-power band; elsewhere it turns by little, and never
    back (no anti-resonance)."""
    from simulator import rotor
    from simulator.engine import SHAFTS

    for shaft in SHAFTS:
        top = max(m.rpm for m in shaft.modes) * 1.3
        speed = np.linspace(0.05 * top, top, 20000)
        v = rotor.order(shaft, speed, np.full(len(speed), metal), np.full(len(speed), 1e-3 + 0j),
                        np.zeros(len(speed), dtype=complex))
        lag = np.degrees(np.unwrap(-np.angle(v)))
        assert np.min(np.diff(lag)) > -0.05, shaft.out  # the lag never turns back
        crits = [(float(rotor.critical_rpm(m, metal)), m.zeta) for m in shaft.modes]
        inside = np.zeros(len(speed), dtype=bool)
        for j, (nc, zeta) in enumerate(crits):
            lo = max([nc * (1 - 3 * zeta)] + [(nc + o) / 2 for o, _ in crits[:j]])
            hi = min([nc * (1 + 3 * zeta)] + [(nc + o) / 2 for o, _ in crits[j + 1:]])
            band = (speed > lo) & (speed < hi)
            inside |= band
            if hi > speed[-1]:
                continue
            turn = lag[band][-1] - lag[band][0]
            assert 100.0 < turn < 200.0, (shaft.out, nc)
            disp = np.abs(v) / speed
            i = int(np.argmax(np.where(band, disp, 0)))
            assert abs(speed[i] / nc - 1) < zeta, (shaft.out, nc)  # inside its half-power band
        # the rest of the range turns no more than the modes' own tails beyond -/+ 3 zeta (a
        # single mode's lag there is within atan(1/3) = 18.4 degrees of 0 or 180): no roll
        # without a resonance
        outside = np.diff(lag)[~inside[1:]]
        assert np.sum(outside) < len(crits) * 2 * 18.5, shaft.out


def test_simulator_truth_lists_modes_and_crossings(tmp_path: Path) -> None:
    from node.cli import main

    out = tmp_path / "t.mcap"
    assert main(["simulate", "--runs", "1", "--seed", "2", "--channels", "nB,yB,yB_ph",
                 "--plateau-scale", "0.05", "--quiet", "--out", str(out)]) == 0
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    rotor_truth = truth["rotor"]
    assert rotor_truth["tracker_s"] > 0
    modes = rotor_truth["modes"]["yB"]
    assert len(modes) == 3 and all(m["af"] == pytest.approx(1 / (2 * m["zeta"]), rel=1e-3) for m in modes)
    crossed = truth["runs"][0]["criticals"]["yB"]
    run = truth["runs"][0]
    assert {c["mode"] for c in crossed} >= {0, 1}
    for c in crossed:
        assert run["start"] <= c["t"] <= run["end"]
        cold = modes[c["mode"]]["rpm_cold"]
        assert 0.9 * cold < c["speed"] <= cold  # the metal only softens the mode
    ups = [c for c in crossed if c["rate_rpm_s"] > 0]
    downs = [c for c in crossed if c["rate_rpm_s"] < 0]
    assert ups and downs


def test_stiffness_fault_moves_its_critical_by_the_square_root() -> None:
    from simulator import campaign, rotor
    from simulator.engine import SHAFTS

    mode = SHAFTS[1].modes[campaign.STIFFNESS_MODE]
    assert rotor.critical_rpm(mode, 200.0, campaign.STIFFNESS_FAULT) == pytest.approx(
        np.sqrt(campaign.STIFFNESS_FAULT) * rotor.critical_rpm(mode, 200.0), rel=1e-12)


@pytest.mark.parametrize("fault, softened", [("stiffness", {0, 1, 2}), ("stiffness-mode", {2})])
def test_the_stiffness_fault_softens_the_shafts_modes(fault: str, softened: set[int]) -> None:
    """A sweep of yB's shaft at a fixed metal temperature crosses each mode before the onset at
    its critical and after it (the 20 s ramp done) at sqrt(0.9) of it: every mode for the
    shaft's stiffness loss, the 0.955 mode alone for "stiffness-mode"."""
    from simulator import campaign, rotor
    from simulator.engine import SHAFTS

    shaft = SHAFTS[1]
    speed = np.concatenate([np.linspace(1000.0, 10000.0, 4000), np.linspace(10000.0, 1000.0, 4000),
                            np.linspace(1000.0, 10000.0, 4000), np.linspace(10000.0, 1000.0, 4000)])
    t = np.arange(len(speed)) * 0.025
    metal = np.full(len(t), 150.0)
    onset = t[8000] - 30.0  # before the second run-up, the ramp done when it starts
    k = campaign.stiffness_loss(fault, len(shaft.modes), t - onset)
    assert set(k) == softened
    found = campaign.crossings(shaft, t, speed, metal, k)
    for c in found:
        cold = rotor.critical_rpm(shaft.modes[c["mode"]], 150.0)
        after = c["t_s"] > onset and c["mode"] in softened
        assert c["speed"] == pytest.approx(cold * (np.sqrt(campaign.STIFFNESS_FAULT) if after else 1.0),
                                           rel=1e-6)  # the truth rounds to 1e-3 rpm
    assert {c["mode"] for c in found if c["t_s"] > onset} == {0, 1, 2}  # each crossed after


def test_ramp_analyser_sample_by_sample_matches_the_offline_analysis() -> None:
    """A simulated run (ramps through yB's criticals) fed one sample at a time: one result per
    ramp, the same criticals as the offline analysis of the ramps found in the whole run,
    and those near the simulator's crossings."""
    from node.contract import PHASE_CHANNELS, SENSOR_CHANNELS
    from node.runtime.ramp_analyser import RampAnalyser
    from simulator.campaign import simulate_campaign
    from simulator.schedule import OC, SimSchedule

    sched = SimSchedule((OC("R1", 6500.0, 20.0, 90.0), OC("R2", 9800.0, 20.0, 80.0)), source="test")
    run = simulate_campaign(1, 4, schedule=sched, plateau_scale=1.0).runs[0]
    assert run.phase is not None
    speed = run.data[:, SENSOR_CHANNELS.index("nB")]
    amp = run.data[:, SENSOR_CHANNELS.index("yB")]
    phase = run.phase[:, PHASE_CHANNELS.index("yB_ph")]
    ra = RampAnalyser(tracker_tau=1.0, min_amplitude=0.2)
    streamed = [t for t in (ra.step(s, a, p) for s, a, p in zip(speed, amp, phase, strict=True))
                if t is not None]
    offline = [analyse(speed[r.start:r.stop], amp[r.start:r.stop], phase[r.start:r.stop],
                       tracker_tau=1.0, min_amplitude=0.2) for r in find_transitions(speed)]
    assert [t.direction for t in streamed] == [t.direction for t in offline]
    assert len(streamed) >= 4  # start, idle -> R1, R1 -> R2, R2 -> idle (and the rundown)
    for a, b in zip(streamed, offline, strict=True):
        assert len(a.criticals) == len(b.criticals)
        for x, y in zip(a.criticals, b.criticals, strict=True):
            assert x.speed == pytest.approx(y.speed, rel=3e-3)
    found = [c.speed for t in streamed for c in t.criticals]
    truth = [c for c in run.truth["criticals"]["yB"] if abs(c["rate_rpm_s"]) > 20]
    assert found and all(min(abs(f / c["speed"] - 1) for c in truth) < 0.01 for f in found)


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_a_ramp_of_few_bins_or_absurd_speeds_gives_no_critical_and_no_error(n: int) -> None:
    """A speed of 1e300 on one sample (a hostile or broken bed) leaves a ramp of a few speed bins:
    the smoothing keeps each array's length (np.convolve's "same" once gave the kernel's)."""
    from node.runtime.transient import _moving_average

    x = np.arange(n, dtype=float) + 1j
    assert len(_moving_average(x, 5)) == n
    speed = np.r_[np.linspace(1500.0, 1600.0, 40), 1e300, np.linspace(1600.0, 1700.0, 40)]
    amp = np.full(speed.size, 2.0)
    phase = np.full(speed.size, 30.0)
    assert analyse(speed, amp, phase).criticals == []
