"""``ordervib predict`` and the prediction behind it: a planned profile's expected orders,
one-line errors for bad profiles, and a held-out run's prediction against its measurement."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from node.cli import main
from node.contract import OrdervibError
from node.models.bundle import load_model
from node.runtime.history import HISTORY_CHANNELS
from node.training.prediction import (
    MEAN_MODULUS,
    Profile,
    RecordedPrediction,
    fit_interval_widths,
    history_after,
    predict_profile,
    predict_recorded_run,
    predict_recorded_runs,
    predict_runs,
    schedule_profile,
    stated_history,
)
from node.training.prediction_aids import AmplitudeBound, InputFill, IntervalWidths
from node.training.runs import read_runs

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "recordings" / "engine1_runs.mcap"
FAULT = ROOT / "recordings" / "engine1_fault.mcap"
SCHEDULE = ROOT / "recordings" / "engine1_runs.schedule.toml"


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    """A state-space model (wdmd) on the speed, a temperature and the engine history."""
    out = tmp_path_factory.mktemp("predict") / "m"
    assert main(["train", str(RUNS), "--schedule", str(SCHEDULE), "--out", str(out), "--method", "wdmd",
                 "--inputs", "nB,tF,hist_energy", "--history", "--no-curve-candidates", "--target", "yB",
                 "--quiet", "--workers", "1"]) == 0
    return out


@pytest.fixture(scope="module")
def train_runs():
    return read_runs(str(RUNS))


def _read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """A prediction CSV's notes (the lines above the header, without "# ") and its rows."""
    with open(path, newline="") as f:
        lines = f.read().splitlines()
    notes = [line[2:] for line in lines if line.startswith("# ")]
    return notes, list(csv.DictReader(line for line in lines if not line.startswith("#")))


@pytest.mark.parametrize("text, message", [
    (None, "not found"),
    ("", "empty"),
    ("t,nA\n0,1\n1,2\n", "no column 'nB'"),
    ("t,nB,nB\n0,1,1\n1,2,2\n", "repeated"),
    ("t,nB\n0,0\n", "at least two"),
    ("t,nB\n0,0\n1,abc\n", "line 3: nB 'abc' is not a number"),
    ("t,nB\n0,0\n1,nan\n", "line 3: nB is nan"),
    ("t,nB\n0,0\n1,\n", "line 3: nB '' is not a number"),
    ("t,nB\n0,0\n1\n", "line 3: 1 values for 2 columns"),
    ("t,nB\n0,0\n2,100\n2,200\n", "line 4: time 2 s does not increase"),
])
def test_bad_profiles_are_one_line_errors_before_any_output(model, tmp_path, capsys, text, message):
    prof = tmp_path / "p.csv"
    if text is not None:
        prof.write_text(text)
    out = tmp_path / "out.csv"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ordervib predict: ") and message in err and "\n" not in err, err
    assert not out.exists()


@pytest.mark.parametrize("extra, message", [
    (["--shutdown-hours", "-1"], "--shutdown-hours"),
    (["--energy", "nan"], "--energy"),
    (["--bed", "b1"], "--bed"),
    (["--png", "x.jpg"], "--png must name a .png"),
])
def test_bad_options_are_one_line_errors(model, tmp_path, capsys, extra, message):
    prof = tmp_path / "p.csv"
    prof.write_text("t,nB\n0,0\n10,3900\n")
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out",
                 str(tmp_path / "o.csv"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err, err


def test_planned_profile_gives_a_prediction_per_oc_and_history(model, tmp_path, capsys):
    """A CSV of breakpoints (t, nB only) through every plateau of the schedule, two stated
    shutdowns: the temperature the model takes is filled from its training recordings, the
    CSV has a row per 40 Hz sample and stated history, every OC gets a finite prediction."""
    bundle = load_model(model)
    plan = schedule_profile(bundle.schedule, plateau_s=20.0)
    # a plateau is two rows 20 s apart: the engine runs through them, one engine run
    running = [r for r in plan.runs(off=100.0) if r.column("nB").max() > 100.0]
    assert len(running) == 1 and running[0].column("nB").max() == max(oc.speed for oc in bundle.schedule.ocs)
    prof = tmp_path / "plan.csv"
    prof.write_text("t,nB\n" + "".join(f"{t:g},{v:g}\n" for t, v in zip(plan.t, plan.data[:, 0])))
    out, png, hist = tmp_path / "pred.csv", tmp_path / "pred.png", tmp_path / "hist.png"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out),
                 "--png", str(png), "--history-png", str(hist), "--shutdown-hours", "0.5", "24",
                 "--energy", "40000", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "OC13" in text and "prediction written to" in text
    notes, rows = _read(out)
    assert list(rows[0]) == ["history", "t", "oc", "outside", "yB", "yB_lo", "yB_hi", "yB_envelope",
                             *HISTORY_CHANNELS, "nB", "tF", "tH", "tI"]
    assert any(n.startswith("filled tF, tH, tI: from the 4 training runs the model keeps") for n in notes)
    assert any(n.startswith("bounds: amplitudes >= 0") for n in notes)
    assert any(n.startswith("interval: yB_lo..yB_hi: 90 % interval") for n in notes)
    assert sum(n.startswith("bounds acted (") for n in notes) == 2  # one per stated history
    assert {r["history"] for r in rows} == {"0.5", "24"}
    n = int(round((plan.t[-1] - plan.t[0]) * 40)) + 1
    assert len(rows) == 2 * n
    for h in ("0.5", "24"):
        mine = [r for r in rows if r["history"] == h]
        for oc in bundle.schedule.names:
            y = [float(r["yB"]) for r in mine if r["oc"] == oc and r["yB"]]
            assert y and np.isfinite(y).all(), (h, oc)
        assert all(r["tF"] for r in mine)  # filled
    # the stated history: the energy carried fades with the hours stood (cooling per hour)
    on = 0.05 * max(oc.speed for oc in bundle.schedule.ocs)  # the engine runs from here
    e0 = {h: float(next(r for r in rows if r["history"] == h and float(r["nB"]) >= on)["hist_energy"])
          for h in ("0.5", "24")}
    cooling = bundle.config.history_cooling
    assert e0["0.5"] == pytest.approx(max(0.0, 40000 - 0.5 * cooling), abs=1.0)
    assert e0["24"] == pytest.approx(max(0.0, 40000 - 24 * cooling), abs=1.0) and e0["24"] < e0["0.5"]
    assert png.stat().st_size > 10_000 and hist.stat().st_size > 10_000
    # a schedule's plateaus directly
    assert main(["predict", "--model", str(model), "--profile", str(SCHEDULE), "--plateau-s", "5",
                 "--out", str(tmp_path / "s.csv"), "--quiet"]) == 0


def test_a_missing_input_without_training_runs_is_one_line(model, train_runs):
    bundle = load_model(model)
    plan = schedule_profile(bundle.schedule, plateau_s=5.0)
    with pytest.raises(OrdervibError, match="'tF'"):
        predict_runs(bundle, plan.runs())
    fill = InputFill.fit(train_runs, bundle.schedule, ["tF", "tI", "tH", "zZ"])
    assert fill.channels == ("tF", "tI", "tH")  # what the runs hold
    assert np.isfinite(predict_runs(bundle, plan.runs(), fill=fill).predicted).any()


def test_held_out_run_predicted_from_its_own_profile_against_its_measurement(model, train_runs):
    """The fault run (run 5 of the engine) from its own inputs and the history of runs 1-4:
    eps_td per OC is finite for every OC; chaining the prediction (each OC seeded from the
    prediction before) does better than the node's models started from rest."""
    bundle = load_model(model)
    run = read_runs(str(FAULT))[0]
    engine = history_after(train_runs, bundle)
    assert engine.last_on_t is not None and train_runs[-1].t[0] < engine.last_on_t <= train_runs[-1].t[-1]
    chained = predict_recorded_run(bundle, run, engine)
    assert chained.eps.shape == (1, len(bundle.schedule.ocs))
    assert np.isfinite(chained.eps).all() and (chained.eps > 0).all()
    absent = predict_recorded_run(bundle, run, engine, seed="absent")
    assert np.mean(chained.eps) < np.mean(absent.eps)
    np.testing.assert_array_equal(chained.measured[:, 0], run.column("yB"))
    p = chained.prediction
    assert p.filled == () and p.t.size == run.t.size and set(p.oc.tolist()) == set(range(-1, 12))
    from replay.views.prediction_plots import fig_prediction
    fig = fig_prediction(chained)  # panel IV: speed, then measured and predicted yB with eps in the title
    assert len(fig.axes) == 2 and "eps_td" in fig.axes[1].get_title(loc="left")
    # a stated shutdown reaches the history channels the node derives
    stated = predict_recorded_run(bundle, run, stated_history(float(run.t[0]), 1.5, 0.0))
    shutdown = stated.prediction.history[:, HISTORY_CHANNELS.index("hist_shutdown")]
    assert shutdown[p.oc >= 0] == pytest.approx(1.5, abs=0.01)


def test_engine_state_file_needs_its_bed_named_when_it_holds_several(model, tmp_path, capsys):
    from node.edges.engine_file import save_engine_states
    from node.runtime.history import EngineState
    state = tmp_path / "engine.json"
    save_engine_states(state, {"b1": EngineState(0.0, 1000.0), "b2": EngineState()})
    prof = tmp_path / "p.csv"
    prof.write_text("t,nB\n0,0\n10,3900\n")
    argv = ["predict", "--model", str(model), "--profile", str(prof), "--out", str(tmp_path / "o.csv"),
            "--engine-state", str(state)]
    assert main(argv) == 2
    assert "name one with --bed" in capsys.readouterr().err
    assert main([*argv, "--bed", "b3"]) == 2
    assert "no bed 'b3'" in capsys.readouterr().err


def test_a_gap_in_the_profile_is_a_shutdown_the_history_sees(model, train_runs):
    """Two engine runs 30 minutes apart in one profile: the second starts a new run for the
    node, and its hist_shutdown is the half hour the engine stood."""
    bundle = load_model(model)
    one = schedule_profile(bundle.schedule, plateau_s=8.0)
    gap = one.t[-1] + 1800.0
    prof = Profile(np.r_[one.t, gap + one.t], np.r_[one.data, one.data], one.channels)
    runs = prof.runs()
    assert len(runs) == 2 and runs[1].shutdown_before == pytest.approx(1800.0, abs=0.1)
    p = predict_runs(bundle, runs, fill=InputFill.fit(train_runs, bundle.schedule, ["tF", "tI", "tH"]))
    shutdown = p.history[:, HISTORY_CHANNELS.index("hist_shutdown")]
    second = (p.run == 1) & (p.oc >= 0)
    on = 0.05 * max(oc.speed for oc in bundle.schedule.ocs)  # the engine runs from here
    ran = [r.t[r.column("nB") >= on] for r in runs]
    stood_h = (ran[1][0] - ran[0][-1]) / 3600.0  # from the last sample it ran to the next
    assert second.sum() > 1000 and shutdown[second] == pytest.approx(stood_h, abs=1e-4)
    assert np.isfinite(p.predicted[second]).any()


def test_recorded_runs_each_with_the_history_the_runs_before_leave(model, train_runs):
    from node.training.prediction import predict_recorded_runs, recorded_eps
    bundle = load_model(model)
    runs = train_runs[:2]
    recs = predict_recorded_runs(bundle, runs)
    assert recs[0].prediction.engine == stated_history(0.0)  # unknown before the first: cold
    assert recs[1].prediction.engine == history_after(runs[:1], bundle)
    np.testing.assert_array_equal(recs[1].eps, predict_recorded_run(bundle, runs[1],
                                                                     history_after(runs[:1], bundle)).eps)
    pooled = recorded_eps(recs)
    assert pooled.shape == (1, 12) and np.isfinite(pooled).all()
    lo, hi = np.minimum(recs[0].eps, recs[1].eps), np.maximum(recs[0].eps, recs[1].eps)
    assert (pooled >= lo - 1e-12).all() and (pooled <= hi + 1e-12).all()  # pooled lies between


def test_a_stated_history_the_model_cannot_use_is_one_warning(tmp_path, capsys):
    """A model without an engine-history input: --shutdown-hours changes nothing, and says so
    once; the history model of the module says nothing of the kind."""
    plain = tmp_path / "plain"
    assert main(["train", str(RUNS), "--schedule", str(SCHEDULE), "--out", str(plain), "--method", "lasso",
                 "--inputs", "nB", "--no-curve-candidates", "--no-prom", "--target", "yB", "--quiet",
                 "--workers", "1"]) == 0
    capsys.readouterr()
    args = ["--profile", str(SCHEDULE), "--plateau-s", "5", "--shutdown-hours", "0.5", "24", "--quiet"]
    assert main(["predict", "--model", str(plain), "--out", str(tmp_path / "p.csv"), *args]) == 0
    err = capsys.readouterr().err.splitlines()
    warned = [line for line in err if "takes no engine-history input" in line]
    assert len(warned) == 1 and warned[0].startswith("warning: ")
    rows = _read(tmp_path / "p.csv")[1]
    by = {h: [r["yB"] for r in rows if r["history"] == h] for h in ("0.5", "24")}
    assert by["0.5"] == by["24"]  # indeed the same numbers



# -- inputs that follow the plan, predictions within physics (issue 32) ------------------------------
def _plan(order: list[int], holds: list[float], offsets: list[float], ramp: float, schedule) -> Profile:
    """From standstill through the schedule's OCs ``order`` (indices), each at its speed x (1 +
    offset) held ``holds`` s, ramps at ``ramp`` rpm/s, back to standstill."""
    t, v = [0.0, 5.0], [0.0, 0.0]
    for o, hold, off in zip(order, holds, offsets):
        s = schedule.ocs[o].speed * (1.0 + off)
        t += [t[-1] + abs(s - v[-1]) / ramp, 0.0]
        t[-1] = t[-2] + hold
        v += [s, s]
    t.append(t[-1] + v[-1] / ramp)
    v.append(0.0)
    return Profile(np.array(t), np.array(v)[:, None], ("nB",), "nB")


@pytest.fixture(scope="module")
def limits(model, train_runs):
    """The fill, bound and CV interval of the module's model from its training runs."""
    bundle = load_model(model)
    return (InputFill.fit(train_runs, bundle.schedule, ["nA", "tF", "tH", "tI"]),
            AmplitudeBound.fit(train_runs, bundle.schedule, bundle.targets))


@settings(max_examples=5, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_plans_are_never_negative_and_within_the_bound(model, limits, data):
    """Plans of random OC order, plateau lengths, speeds within the schedule's tolerance and ramp
    rates: every predicted amplitude is >= 0 and <= 1.5 x the training runs' largest in that
    OC within 100 rpm (computed here from the runs), and lo <= predicted <= hi."""
    bundle = load_model(model)
    fill, bound = limits
    sched = bundle.schedule
    n = data.draw(st.integers(2, 4))
    order = data.draw(st.permutations(range(len(sched.ocs))))[:n]
    holds = data.draw(st.lists(st.floats(8.0, 25.0), min_size=n, max_size=n))
    offsets = data.draw(st.lists(st.floats(-0.01, 0.01), min_size=n, max_size=n))
    ramp = data.draw(st.floats(60.0, 400.0))
    p = predict_profile(bundle, _plan(order, holds, offsets, ramp, sched), fill=fill, bound=bound)
    y = p.predicted[:, 0]
    ok = np.isfinite(y)
    assert ok.any()
    assert (y[ok] >= 0).all()
    for o in np.unique(p.oc[ok]):
        mine = ok & (p.oc == o)
        cap = bound.limits("yB", int(o), p.speed[mine])
        assert (y[mine] <= cap + 1e-9).all()
    assert (p.lo[ok, 0] <= y[ok]).all() and (y[ok] <= p.hi[ok, 0]).all() and (p.lo[ok, 0] >= 0).all()
    raw = p.raw[:, 0]
    assert ((p.bounded[:, 0] != 0) == (np.isfinite(raw) & (raw != y))).all()


def test_the_bound_is_the_training_runs_largest_in_the_oc_near_the_speed(train_runs):
    """The bound against a brute-force reading of its rule on the training runs (speeds in 5 rpm
    steps, the window inclusive): the same numbers; beyond every training speed, the OC's largest."""
    from node.contract.schedule import load_schedule
    from node.training.dataset import segment_runs
    sched = load_schedule(str(SCHEDULE))
    bound = AmplitudeBound.fit(train_runs, sched, ["yB"])
    segs = segment_runs(train_runs, sched)

    def steps(x):
        return np.round(np.asarray(x, float) / 5.0) * 5.0

    for o in (0, 6, 11):
        mine = [s for s in segs if s.oc == o]
        speed = steps(np.concatenate([train_runs[s.run].column("nB")[s.start:s.stop] for s in mine]))
        y = np.concatenate([train_runs[s.run].column("yB")[s.start:s.stop] for s in mine])
        for q in (sched.ocs[o].speed, sched.ocs[o].speed - 61.0, float(np.nanmedian(speed)) + 2.0):
            near = np.abs(speed - steps(q)) <= 100.0 + 1e-9
            want = 1.5 * np.nanmax(y[near])
            assert float(bound.limits("yB", o, np.array([q]))[0]) == pytest.approx(want, rel=1e-12), (o, q)
        assert float(bound.limits("yB", o, np.array([20000.0]))[0]) == pytest.approx(1.5 * np.nanmax(y))


def test_filled_channels_follow_the_plans_speed(model, train_runs, limits):
    """A profile of only t and nB, its OCs in another order, ramps three times faster than the
    engine's: on each plateau the filled nA lies where the training runs had nA at that nB in
    that OC (within 2 %), and across the plateaus it rises with nB as theirs does."""
    from node.contract import Phase
    from node.training.dataset import label_runs, segment_runs
    bundle = load_model(model)
    fill = limits[0]
    sched = bundle.schedule
    order, offsets = [11, 3, 8, 0, 6], [0.005, -0.005, 0.0, 0.0, 0.008]
    planned = {o: sched.ocs[o].speed * (1.0 + off) for o, off in zip(order, offsets)}
    run = _plan(order, [20.0] * 5, offsets, 270.0, sched).runs(100.0)[0]
    na = fill.fill(run, sched, "nA")
    train_segs = segment_runs(train_runs, sched)
    steady = label_runs([run], sched)[0][1] == Phase.STEADY.code
    medians = []
    for s in segment_runs([run], sched):
        if s.oc not in planned:  # (the detector's passing guess on a ramp)
            continue
        nb = planned[s.oc]
        sl = np.flatnonzero(steady[s.start:s.stop] & (np.abs(run.column("nB")[s.start:s.stop] - nb) < 1.0))
        if not sl.size:  # (the OC passed again on a ramp)
            continue
        sl += s.start  # the plateau
        assert sl.size > 10 * 40
        mine = [t for t in train_segs if t.oc == s.oc]
        ref_b = np.concatenate([train_runs[t.run].column("nB")[t.start:t.stop] for t in mine])
        ref_a = np.concatenate([train_runs[t.run].column("nA")[t.start:t.stop] for t in mine])
        near = np.abs(ref_b - nb) <= 50.0
        assert near.sum() > 100, sched.names[s.oc]
        lo, hi = np.nanpercentile(ref_a[near], [1, 99])
        assert (na[sl] >= 0.98 * lo).all() and (na[sl] <= 1.02 * hi).all(), (sched.names[s.oc], lo, hi)
        medians.append((nb, float(np.median(na[sl])), float(np.nanmedian(ref_a[near]))))
    assert len(medians) == len(order)
    by_speed = sorted(medians)
    assert [m[2] for m in by_speed] == sorted(m[2] for m in by_speed)  # theirs rises with nB ...
    assert [m[1] for m in by_speed] == sorted(m[1] for m in by_speed)  # ... and so does the fill


def test_interval_from_the_chained_training_runs_is_wider_than_the_cv_one(model, train_runs, limits):
    """fit_interval_widths: at least the CV sigma's interval (the same t factor), over four runs,
    and the rule of run levels: t(n-1) x sqrt(between^2 (1 + 1/n) + within^2)."""
    bundle = load_model(model)
    cv = IntervalWidths.from_cv(bundle)
    fitted = fit_interval_widths(bundle, train_runs, limits[1])
    ok = np.isfinite(cv.half) & (fitted.runs >= 2)
    assert ok.any()
    assert (fitted.runs[ok] == 4).all()
    from scipy.stats import t as student
    factor = student.ppf(0.95, 3)
    new_run = np.sqrt(fitted.between ** 2 * 1.25 + fitted.within ** 2)
    np.testing.assert_allclose(fitted.half[ok], factor * np.fmax(new_run, fitted.cv_sigma)[ok])
    assert (fitted.half[ok] >= factor * fitted.cv_sigma[ok] * (1 - 1e-12)).all()


def _synthetic(recs, levels, shift: float, within: float, rng) -> list:
    """The recorded runs ``recs`` with what they measured replaced by a known system: the
    prediction + shift + the run's level + N(0, within) per sample."""
    out = []
    for rec, lv in zip(recs, levels):
        p = rec.prediction.predicted
        y = p + shift + lv + within * rng.standard_normal(p.shape)
        out.append(RecordedPrediction(rec.prediction, y, rec.segments, eps=np.ones((1, 1))))
    return out


def test_interval_recovers_run_levels_and_covers_a_new_run_90_percent(model, train_runs, limits):
    """A known system (each run's level N(0, 4) mm/s, a bias of 1.5, within-run noise 0.5):
    IntervalWidths recovers the bias, the levels' SD and the within-run SD; and over 400 draws
    of four training runs and a new run, 87-95 % of the new run's samples fall in the interval
    (the Student-t prediction interval of a new group; a little over 90 %: the t factor also
    widens the within-run part, known well)."""
    bundle = load_model(model)
    recs = predict_recorded_runs(bundle, train_runs, bound=limits[1])
    rng = np.random.default_rng(7)
    levels = np.array([-5.0, 1.0, 3.0, 6.0])
    w = IntervalWidths.from_recorded(bundle, _synthetic(recs, levels, 1.5, 0.5, rng))
    ok = (w.runs >= 2) & np.isfinite(w.cv_sigma)
    assert ok.any()
    np.testing.assert_allclose(w.offsets()[ok], 1.5 + levels.mean(), atol=0.05)
    np.testing.assert_allclose(w.between[ok], np.std(levels, ddof=1), rtol=0.02)
    np.testing.assert_allclose(w.within[ok], 0.5, rtol=0.05)
    # coverage of a new run, on average over training sets: per sample, in OCs every run reached
    inside, total = 0.0, 0
    for _ in range(400):
        lv = 4.0 * rng.standard_normal(5)
        w = IntervalWidths.from_recorded(bundle, _synthetic(recs, lv[:4], 1.5, 0.5, rng))
        o = np.flatnonzero(ok[0])
        e = 1.5 + lv[4] + 0.5 * rng.standard_normal((200, o.size))  # the new run's residuals
        inside += float(np.sum(np.abs(e - w.offsets()[0, o]) <= w.half[0, o]))
        total += e.size
    assert 0.87 <= inside / total <= 0.95, inside / total


# -- history that counts or says it does not; vector models without a level (issue 32) ---------------
def test_a_history_far_outside_the_training_runs_is_flagged_by_the_envelope(model, tmp_path, capsys):
    """A stated energy far beyond any the training runs carried: in every OC whose model takes
    hist_energy, each predicted row's yB_envelope is above 1 and the notes say OUTSIDE; after
    the history the training runs themselves leave, every envelope there is ten times smaller."""
    bundle = load_model(model)
    with_history = {n for n in bundle.schedule.names
                    if (r := bundle.bundles[0].oc(n)) is not None and r.model is not None
                    and "hist_energy" in r.inputs}
    assert with_history
    prof = tmp_path / "plan.csv"
    plan = schedule_profile(bundle.schedule, plateau_s=10.0)
    prof.write_text("t,nB\n" + "".join(f"{t:g},{v:g}\n" for t, v in zip(plan.t, plan.data[:, 0])))
    out = tmp_path / "far.csv"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out),
                 "--shutdown-hours", "0", "--energy", "1e9", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "yB: OUTSIDE the training region" in err
    notes, rows = _read(out)
    assert any(n.startswith("envelope: yB: OUTSIDE the training region") for n in notes)
    mine = [r for r in rows if r["oc"] in with_history and r["yB"]]
    assert mine and all(float(r["yB_envelope"]) > 1.0 for r in mine)
    assert {r["oc"] for r in mine} == with_history
    # the same plan after the training runs' own history
    near = predict_profile(bundle, plan, history_after(read_runs(str(RUNS)), bundle), fill=InputFill.fit(
        read_runs(str(RUNS)), bundle.schedule, ["tF", "tH", "tI"]))
    far = predict_profile(bundle, plan, stated_history(float(plan.t[0]), 0.0, 1e9), fill=InputFill.fit(
        read_runs(str(RUNS)), bundle.schedule, ["tF", "tH", "tI"]))
    idx = [bundle.schedule.names.index(n) for n in with_history]
    ok = np.isfinite(near.predicted[:, 0]) & np.isin(near.oc, idx)
    assert ok.any() and np.isfinite(near.envelope[ok, 0]).all()
    assert far.outside()[ok, 0].all()
    assert np.min(far.envelope[ok, 0]) > 10.0 * np.max(near.envelope[ok, 0])


def test_a_vector_model_without_a_level_predicts_the_mean_modulus(phased):
    """The phased model's vector curves, chained (no measured level, no phase): the node alone
    predicts the runs' mean vector, whose modulus is below their mean amplitude; the chain
    takes the runs' mean amplitude in the OC at the speed instead, so that on the training runs
    the measured / predicted ratio in those OCs is near 1, and never meaningfully further from 1
    than the node's own."""
    from node.training.fit import load_runs

    bundle = load_model(phased / "model")
    runs = load_runs([str(phased / "train.mcap")], quiet=True)
    vector = [o for o, n in enumerate(bundle.schedule.names)
              if (r := bundle.bundles[0].oc(n)) is not None and r.model is not None
              and r.kind == "curve:vector"]
    assert vector
    recs = predict_recorded_runs(bundle, runs, levels=InputFill.fit(runs, bundle.schedule, ["yB"]))
    got, own = [], []
    for o in vector:
        y = np.concatenate([rec.measured[rec.prediction.oc == o, 0] for rec in recs])
        p = np.concatenate([rec.prediction.predicted[rec.prediction.oc == o, 0] for rec in recs])
        raw = np.concatenate([rec.prediction.raw[rec.prediction.oc == o, 0] for rec in recs])
        code = np.concatenate([rec.prediction.bounded[rec.prediction.oc == o, 0] for rec in recs])
        ok = np.isfinite(y) & np.isfinite(p) & np.isfinite(raw)
        assert ok.any() and (code[ok] == MEAN_MODULUS).all()
        got.append(np.mean(y[ok]) / np.mean(p[ok]))
        own.append(np.mean(y[ok]) / np.mean(raw[ok]))
    got_err, own_err = np.abs(np.log(got)), np.abs(np.log(own))
    assert np.median(got_err) < np.log(1.25)
    # never worse than the node's own beyond 2 % (on the modal rotor's runs the imbalance angles
    # scatter little, so the node's own modulus of the mean is often close already)
    assert all(g <= max(o, np.log(1.02)) for g, o in zip(got_err, own_err)), (got_err, own_err)


# -- plans held to what the model knows --------------------------------------------------------------
def _plan_csv(path: Path, rows: list[tuple[float, float]]) -> Path:
    path.write_text("t,nB\n" + "".join(f"{t:g},{v:g}\n" for t, v in rows))
    return path


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("warning: the plan")]


def test_a_plan_beyond_the_training_speeds_is_marked_said_once_and_exits_3(model, tmp_path, capsys):
    """Plateaus at 10,500 and 11,500 rpm, above the 9,814 the training runs reached (before: blank
    rows, exit 0, no word): every sample above is marked 'speed', one warning says which, exit 3."""
    prof = _plan_csv(tmp_path / "high.csv", [(0, 0), (10, 0), (40, 9800), (100, 9800), (105, 10500),
                                             (165, 10500), (170, 11500), (230, 11500), (270, 0), (280, 0)])
    out = tmp_path / "high.out.csv"
    argv = ["predict", "--model", str(model), "--profile", str(prof), "--out", str(out), "--quiet"]
    assert main(argv) == 3
    err = capsys.readouterr().err
    said = _warnings(err)
    assert len(said) == 1 and "beyond the training runs' 18-9,814 rpm" in said[0], err
    assert "column outside" in said[0] and said[0].endswith("exit status 3")
    notes, rows = _read(out)
    assert any(n.startswith("outside: the plan leaves what the model knows") for n in notes)
    speed = np.array([float(r["nB"]) for r in rows])
    marked = np.array([r["outside"] for r in rows])
    assert (marked[speed > 9814.0] == "speed").all() and (marked[speed <= 9814.0] == "").all()
    assert f"{int((speed > 9814.0).sum()):,} with nB beyond" in said[0]
    # the same as JSON: the counts and the status
    assert main([*argv, "--json"]) == 3
    data = json.loads(capsys.readouterr().out)
    assert data["outside"]["speed"] == int((speed > 9814.0).sum()) and data["outside"]["no_oc"] == 0
    assert data["exit_status"] == 3 and data["rows"] == len(rows)


def test_a_plan_held_at_a_speed_no_oc_has_is_marked_said_once_and_exits_3(model, tmp_path, capsys):
    """A plan held at 1,500 rpm from light-off (the start, the first OC's transition, never
    reaching its plateau): the hold's samples are marked 'no_oc' and left blank, the ramps are
    the start's and the rundown's, not marked; one line says it and that no OC was found."""
    prof = _plan_csv(tmp_path / "low.csv", [(0, 0), (10, 0), (20, 1500), (240, 1500), (250, 0)])
    out = tmp_path / "low.out.csv"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out)]) == 3
    err = capsys.readouterr().err
    said = _warnings(err)
    assert len(said) == 1 and "'no_oc'" in said[0] and "found no OC of the schedule anywhere" in said[0]
    assert sum("no OC" in line for line in err.splitlines()) == 1, err
    _, rows = _read(out)
    held = [float(r["nB"]) for r in rows if r["outside"] == "no_oc"]
    assert len(held) >= 200 * 40 and all(abs(v - 1500.0) <= 0.25 * 0.02 * 1500.0 for v in held)
    assert {r["outside"] for r in rows if float(r["nB"]) == 1500.0} == {"no_oc"}
    ramp = [r for r in rows if 100.0 < float(r["nB"]) < 1400.0]
    assert ramp and all(r["outside"] == "" for r in ramp)
    assert not any(r["yB"] for r in rows if r["outside"] == "no_oc")


def test_a_hold_between_two_plateaus_is_marked_no_oc_and_left_blank(model, tmp_path, capsys):
    """A plan that reaches the first OC, then holds 60 s at a speed between two OCs' plateaus
    (a transition held): the hold is 'no_oc' and blank, the OC's plateau is predicted and not
    marked."""
    bundle = load_model(model)
    first, second = bundle.schedule.ocs[0].speed, bundle.schedule.ocs[1].speed
    mid = 0.5 * (first + second)
    prof = _plan_csv(tmp_path / "mid.csv", [(0, 0), (30, first), (150, first), (160, mid), (220, mid),
                                            (240, 0)])
    out = tmp_path / "mid.out.csv"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out)]) == 3
    _, rows = _read(out)
    held = [r for r in rows if float(r["nB"]) == mid]
    assert held and {r["outside"] for r in held} == {"no_oc"} and not any(r["yB"] for r in held)
    plateau = [r for r in rows if float(r["nB"]) == first]
    assert {r["outside"] for r in plateau} == {""} and all(r["yB"] for r in plateau[-200:])
    assert "'no_oc'" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("t,nB\n0,0\n10,3900\n20,-3900\n", "line 4: nB -3900 rpm is negative"),
    ("t,nB\n0,0\n10,nan\n", "line 3: nB is nan"),
    ("t,nB\n0,0\n10,inf\n", "line 3: nB is inf"),
])
def test_a_negative_or_non_finite_speed_is_one_line_exit_2_and_no_output(model, tmp_path, capsys, text,
                                                                          message):
    prof = tmp_path / "bad.csv"
    prof.write_text(text)
    out = tmp_path / "bad.out.csv"
    assert main(["predict", "--model", str(model), "--profile", str(prof), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ordervib predict: profile ") and message in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("bad, word", [(-3900.0, "negative"), (np.nan, "not a finite number"),
                                       (np.inf, "not a finite number")])
def test_the_library_refuses_a_negative_or_non_finite_planned_speed(model, bad, word):
    bundle = load_model(model)
    plan = Profile(np.array([0.0, 10.0, 20.0]), np.array([[0.0], [3900.0], [bad]]), ("nB",), "nB")
    with pytest.raises(OrdervibError, match=word):
        predict_profile(bundle, plan)


def test_marks_leave_ramps_and_an_oc_plateau_found_late_alone():
    """Synthetic: a plateau whose OC the node finds after a few samples is not marked; one where
    the node is steady in no OC is; ramps are not; a speed above the range is 'beyond' whatever the OC."""
    from node.training.prediction_reach import BEYOND, NO_OC, SpeedRange, plan_marks

    ramp = np.linspace(0.0, 3000.0, 200)
    speed = np.r_[ramp, np.full(400, 3000.0), np.linspace(3000.0, 1500.0, 100), np.full(400, 1500.0),
                  np.full(300, 12000.0)]
    steady = np.zeros(speed.size, dtype=bool)
    steady[210:600] = True  # the OC at 3,000 rpm, found 10 samples into its plateau
    steady[1100:] = True  # an OC in force while the speed is beyond the range
    marks = plan_marks(speed, steady, np.zeros(speed.size, int), SpeedRange(0.0, 10000.0, "test"), 0.02,
                       300.0, 5.0)
    assert (marks[:699] == 0).all()  # (sample 699: the ramp reaches 1,500 rpm, the plateau)
    assert (marks[700:1100][speed[700:1100] == 1500.0] == NO_OC).all()
    assert (marks[1100:] == BEYOND).all()
