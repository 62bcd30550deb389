"""OC detection from the switch speed: the schedule's sequence, and its edge cases."""

from __future__ import annotations

import numpy as np
import pytest

from node.contract.errors import OrdervibError
from node.contract.schedule import OperatingCondition, Schedule, load_schedule
from node.runtime.ocdetect import OCDetector, Phase

FS = 40.0
SCHED = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0),
                  OperatingCondition("C", 5000.0), OperatingCondition("D", 8000.0)))


def profile(points: list[tuple[float, float]], noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """Piecewise-linear speed through (duration s, speed rpm) points from 0 rpm, at 40 Hz."""
    speed, out = 0.0, []
    for dur, target in points:
        n = int(dur * FS)
        out.append(np.linspace(speed, target, n, endpoint=False) if n else np.zeros(0))
        speed = target
    x = np.concatenate(out + [np.full(1, speed)])
    return x + noise * np.random.default_rng(seed).standard_normal(x.size)


def events(speed: np.ndarray, schedule: Schedule = SCHED) -> list[str]:
    oc, ph = OCDetector(schedule, fs=FS).label(speed)
    change = np.flatnonzero((np.diff(oc) != 0) | (np.diff(ph) != 0)) + 1
    out = []
    for k in change:
        out.append("off" if ph[k] == 0 else schedule.segments[oc[k]] + ("T" if ph[k] == 1 else "S"))
    return out


NORMAL = [(10, 2500), (15, 2500), (10, 4000), (20, 4000), (10, 6000), (20, 6000),
          (8, 5000), (20, 5000), (15, 8000), (20, 8000), (10, 2500), (10, 2500), (5, 0), (5, 0)]


def test_schedule_sequence_with_speed_noise():
    # 0.2 % speed noise, as a real pick-up gives, must not flicker at plateau edges
    ev = events(profile(NORMAL, noise=8.0))
    assert ev == ["AT", "AS", "BT", "BS", "CT", "CS", "DT", "DS", "rundownT", "off"]


def test_switch_times_follow_the_speed():
    speed = profile(NORMAL)
    oc, ph = OCDetector(SCHED, fs=FS).label(speed)
    k_leave_a = int((10 + 15 + 10 + 20) * FS)  # B's ramp begins here
    first_bt = np.flatnonzero((oc == 1) & (ph == 1))[0]
    assert 0 < first_bt - k_leave_a <= 2 * FS  # within 2 s of the speed leaving A
    k_reach_b = k_leave_a + int(10 * FS)
    first_bs = np.flatnonzero((oc == 1) & (ph == 2))[0]
    assert 0 < first_bs - k_reach_b <= 2 * FS


def test_noise_at_a_plateau_edge_does_not_toggle():
    # the speed holds exactly at the edge of A's band (4000 * 1.019) with noise
    speed = profile([(10, 2500), (10, 2500), (10, 4076), (60, 4076)], noise=15.0, seed=3)
    ev = events(speed)
    assert ev.count("AS") == 1
    assert ev[-1] == "AS"


def test_ramp_through_other_plateaus_is_not_steady():
    # D is reached from C through B's band (6000) at 100 rpm/s: no B steady on the way
    assert "BS" not in events(profile([(10, 2500), (10, 2500), (8, 4000), (10, 4000),
                                        (10, 5000), (10, 5000), (30, 8000), (10, 8000)]))


def test_aborted_run_then_resumed():
    # after A and B the speed falls back to idle, holds, then the run resumes with C.
    # Causally the fall first looks like the transition into C (the next OC down);
    # once it goes past C's band it is the rundown (no later OC below), and the resumed
    # run leaves the speed it held for C.
    speed = profile([(10, 2500), (10, 2500), (10, 4000), (20, 4000), (10, 6000), (20, 6000),
                     (10, 2500), (20, 2500), (10, 5000), (20, 5000)])
    assert events(speed) == ["AT", "AS", "BT", "BS", "CT", "rundownT", "CT", "CS"]
    oc, ph = OCDetector(SCHED, fs=FS).label(speed)
    wrong = np.flatnonzero((oc == 2) & (ph == 1) & (np.arange(speed.size) < 90 * FS))
    assert wrong.size < 6 * FS  # the mistaken C transition lasts only while passing C


def test_repeated_oc_is_recognised():
    # B is run twice: after B the speed returns to A's plateau, then goes to B again
    ev = events(profile([(10, 2500), (10, 2500), (10, 4000), (20, 4000), (10, 6000), (20, 6000),
                         (10, 4000), (20, 4000), (10, 6000), (20, 6000)]))
    assert ev[:4] == ["AT", "AS", "BT", "BS"]
    assert ev[-1] == "BS" and ev.count("AS") == 2


def test_dropouts_hold_the_state_and_shutdown_resets():
    speed = profile(NORMAL)
    speed[int(40 * FS): int(42 * FS)] = np.nan
    assert events(speed) == ["AT", "AS", "BT", "BS", "CT", "CS", "DT", "DS", "rundownT", "off"]
    # a second run in the same stream starts again at the first OC
    twice = np.concatenate([profile(NORMAL), profile(NORMAL)])
    assert events(twice) == ["AT", "AS", "BT", "BS", "CT", "CS", "DT", "DS", "rundownT", "off"] * 2


def test_step_equals_label():
    speed = profile(NORMAL, noise=8.0)
    det = OCDetector(SCHED, fs=FS)
    stepped = [det.step(v) for v in speed]
    oc, ph = OCDetector(SCHED, fs=FS).label(speed)
    codes = {Phase.OFF: 0, Phase.TRANSITION: 1, Phase.STEADY: 2}
    assert [(-1 if s.oc is None else s.oc) for s in stepped] == oc.tolist()
    assert [codes[s.phase] for s in stepped] == ph.tolist()


def test_schedule_file_errors(tmp_path):
    with pytest.raises(OrdervibError, match="not found"):
        load_schedule(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("switch = [")
    with pytest.raises(OrdervibError, match="TOML"):
        load_schedule(bad)
    bad.write_text('[[oc]]\nname = "A"\n')
    with pytest.raises(OrdervibError, match="speed"):
        load_schedule(bad)
    bad.write_text('[[oc]]\nname = "A"\nspeed = 1.0\n[[oc]]\nname = "A"\nspeed = 2.0\n')
    with pytest.raises(OrdervibError, match="repeats"):
        load_schedule(bad)
    bad.write_text('[[oc]]\nname = "rundown"\nspeed = 1.0\n')
    with pytest.raises(OrdervibError, match="reserved"):
        load_schedule(bad)
    good = tmp_path / "good.toml"
    good.write_text(SCHED.to_toml())
    assert load_schedule(good) == SCHED


def _first(speed: np.ndarray, oc: int, phase: int) -> int:
    found, ph = OCDetector(SCHED, fs=FS).label(speed)
    return int(np.flatnonzero((found == oc) & (ph == phase))[0])


def test_light_off_starts_the_first_oc():
    # the start is A's transition from the first speed above off (5 % of 8000 rpm = 400 rpm)
    speed = profile([(20, 4000), (20, 4000)])
    oc, ph = OCDetector(SCHED, fs=FS).label(speed)
    above = int(np.flatnonzero(speed >= 400.0)[0]) + int(0.25 * FS) - 1  # above it for depart_s
    assert (oc[:above] == -1).all() and (ph[:above] == Phase.OFF.code).all()
    assert oc[above] == 0 and ph[above] == Phase.TRANSITION.code
    assert events(speed) == ["AT", "AS"]


def test_a_start_that_holds_at_idle_stays_the_start():
    # idle (2500 rpm, no plateau) held for 60 s: still A's transition, never off
    speed = profile([(10, 2500), (60, 2500), (10, 4000), (20, 4000)], noise=8.0)
    assert events(speed) == ["AT", "AS"]
    oc, _ = OCDetector(SCHED, fs=FS).label(speed)
    assert (oc[int(2 * FS):] == 0).all()  # (400 rpm at 1.6 s)


def test_rundown_to_standstill():
    # after the last plateau the fall to 0 rpm is the rundown (index len(ocs)), through an idle
    # hold, and off only below the off level
    speed = profile(NORMAL)
    oc, ph = OCDetector(SCHED, fs=FS).label(speed)
    rundown = np.flatnonzero(oc == SCHED.rundown)
    assert (ph[rundown] == Phase.TRANSITION.code).all()
    assert np.all(np.diff(rundown) == 1)  # one stretch
    leave_d = int(sum(d for d, _ in NORMAL[:10]) * FS)
    assert 0 < rundown[0] - leave_d <= 2 * FS  # from the departure of D's plateau
    off = int(np.flatnonzero((np.arange(speed.size) > leave_d) & (speed < 400.0))[0])
    assert rundown[-1] == off - 1  # to standstill


def test_noise_at_the_off_level_is_no_start():
    # a rundown that ends with the speed hovering at the off level: off, never a new start
    speed = np.r_[profile(NORMAL)[:-int(10 * FS)], np.full(int(10 * FS), 400.0)]
    speed[-int(10 * FS):] += 8.0 * np.random.default_rng(1).standard_normal(int(10 * FS))
    assert events(speed)[-2:] == ["rundownT", "off"]


def test_rundown_interrupted_by_a_rerun_plateau():
    # after D the speed falls, then holds at B's plateau (a re-run): B takes over once it has
    # held for settle_s; the final fall heads for C (the OC after B) and past it is the rundown
    speed = profile(NORMAL[:10] + [(10, 6000), (30, 6000), (10, 0), (5, 0)])
    assert events(speed) == ["AT", "AS", "BT", "BS", "CT", "CS", "DT", "DS", "rundownT", "BS",
                             "CT", "rundownT", "off"]


def test_a_recording_that_begins_mid_run():
    # the first speed above off is on B's plateau: no start, B once it has held
    speed = profile([(0, 6000), (20, 6000), (10, 8000), (20, 8000)])[1:]
    assert events(speed)[:2] == ["BS", "DT"]
    assert _first(speed, 1, Phase.STEADY.code) >= 5 * FS - 1  # (settle_s: an unexpected plateau)


def test_the_start_has_its_model_until_it_leaves_the_speed_it_held():
    # models=True: the start's model index (len(ocs) + 1) from light-off until the speed leaves
    # the idle it held, the first OC's from there; the OCs as the contract labels them unchanged
    speed = profile([(10, 2500), (30, 2500), (10, 4000), (20, 4000)], noise=8.0)
    det = OCDetector(SCHED, fs=FS)
    seg, ph = det.label(speed, models=True)
    oc, ph2 = OCDetector(SCHED, fs=FS).label(speed)
    own = seg != SCHED.start
    assert (ph == ph2).all() and (oc[~own] == 0).all() and (seg[own] == oc[own]).all()
    leave = int(40 * FS)  # the ramp from idle begins
    switch = int(np.flatnonzero(seg == 0)[0])
    assert 0 < switch - leave <= 2 * FS
    assert (seg[int(2 * FS):switch] == SCHED.start).all()
    # without a hold the start's model runs up to the plateau
    seg, _ = OCDetector(SCHED, fs=FS).label(profile([(20, 4000), (20, 4000)]), models=True)
    first_a = int(np.flatnonzero(seg == 0)[0])
    assert (seg[first_a - 10:first_a] == SCHED.start).all()
    assert SCHED.models[SCHED.start] == "A:start"
