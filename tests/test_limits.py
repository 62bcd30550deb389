"""Acceptance limits (docs/contract.md sections 2 and 4): the schedule's ``[[limit]]`` tables
checked as inputs are, the limit in force at each sample, and the pass-off verdict."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from node.cli import main
from node.contract import OrdervibError, load_schedule
from node.contract.schedule import Limit, Schedule, limit_in_force

PLAIN = ('switch = "nB"\ntolerance = 0.02\n[[oc]]\nname = "OC3"\nspeed = 4700.0\n'
         '[[oc]]\nname = "OC7"\nspeed = 8000.0\n')
BAND = '[[limit]]\ntarget = "yB"\nmax = 12.0\nfrom_speed = 7000.0\nto_speed = 9900.0\n'


def _load(tmp_path: Path, text: str) -> Schedule:
    path = tmp_path / "s.toml"
    path.write_text(text, encoding="utf-8")
    return load_schedule(path)


def test_limits_are_read_kept_and_written_back(tmp_path: Path) -> None:
    s = _load(tmp_path, "separation_margin = 0.15\n" + PLAIN + BAND
              + '[[limit]]\ntarget = "yA"\nmax = 4\noc = "rundown"\n')
    assert s.limits == (Limit("yB", 12.0, 7000.0, 9900.0), Limit("yA", 4.0, oc="rundown"))
    assert s.separation_margin == 0.15
    assert s.limits_of("yB") == s.limits[:1]
    assert Schedule.from_dict(s.to_dict()) == s
    assert _load(tmp_path, s.to_toml()) == s
    plain = _load(tmp_path, PLAIN)
    assert "limit" not in plain.to_dict() and plain.limits == () and plain != s


@pytest.mark.parametrize("table, words", [
    ('target = "yB"\nmax = 12.0\nfrom_speed = 9000.0\nto_speed = 7000.0\n', "inverted speed band"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = 7000.0\nto_speed = 7000.0\n', "inverted speed band"),
    ('target = "yB"\nmax = nan\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = inf\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = -1.0\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = 0\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = true\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = "12"\n', "max must be a positive finite number"),
    ('target = "yB"\n', "no max"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = -5.0\n', "from_speed must be a finite number >= 0"),
    ('target = "yB"\nmax = 12.0\nto_speed = inf\n', "to_speed must be a finite number >= 0"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = 7000.0\noc = "OC7"\n', "both a speed band and an oc"),
    ('target = "yB"\nmax = 12.0\noc = "OC9"\n', "oc 'OC9' is none of the schedule's segments"),
    ('target = "yB"\nmax = 12.0\noc = 7\n', "oc must be an OC's name"),
    ('target = "y*"\nmax = 12.0\n', "target must name a channel"),
    ('target = "oc"\nmax = 12.0\n', "target must name a channel"),
    ('max = 12.0\n', "target must name a channel"),
    ('target = "yB"\nmax = 12.0\nto_sped = 9.0\n', "unknown key(s) to_sped"),
])
def test_a_bad_limit_is_a_one_line_error(tmp_path: Path, table: str, words: str) -> None:
    with pytest.raises(OrdervibError) as exc:
        _load(tmp_path, PLAIN + "[[limit]]\n" + table)
    assert words in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("extra, words", [
    ("limit = 3\n", "limit must be an array of tables"),
    ("separation_margin = 1.5\n", "separation_margin must be in (0, 1)"),
    ('separation_margin = "wide"\n', "separation_margin must be a number"),
])
def test_a_bad_limit_setting_is_a_one_line_error(tmp_path: Path, extra: str, words: str) -> None:
    with pytest.raises(OrdervibError) as exc:
        _load(tmp_path, extra + PLAIN)
    assert words in str(exc.value)


def test_a_limit_on_a_target_the_model_lacks_is_refused() -> None:
    s = Schedule.from_dict({"oc": [{"name": "A", "speed": 4000.0}], "limit": [{"target": "yD", "max": 3.0}]})
    s.check_targets(["yD"])
    with pytest.raises(OrdervibError, match="on yD, which the model does not hold"):
        s.check_targets(["yA", "yB"])


def test_train_reports_a_bad_limit_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "r.mcap"
    rec.write_bytes(b"")
    sched = tmp_path / "s.toml"
    sched.write_text(PLAIN + '[[limit]]\ntarget = "yB"\nmax = 12.0\nfrom_speed = 9.0\nto_speed = 1.0\n')
    assert main(["train", str(rec), "--schedule", str(sched), "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ordervib train: ") and "inverted speed band" in err and len(err.splitlines()) == 1


def test_the_limit_in_force_is_the_smallest_that_applies() -> None:
    limits = (Limit("yB", 12.0, 7000.0, 9900.0), Limit("yB", 10.0, oc="OC7"), Limit("yB", 20.0),
              Limit("yB", 11.0, from_speed=9000.0))
    assert limit_in_force(limits, 8000.0, "OC7") == 10.0
    assert limit_in_force(limits, 7000.0, "OC3") == 12.0  # band ends included
    assert limit_in_force(limits, 9950.0, "OC3") == 11.0  # one end alone: open on the other
    assert limit_in_force(limits, 100.0, None) == 20.0  # everywhere
    assert limit_in_force(limits[:2], 100.0, None) is None


# -- the limit and the verdict on simulated runs ----------------------------------------------------

@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Four training runs and two held-out ones of one simulated engine (nB, yB, tF; short
    plateaus), a schedule with a speed band and an OC limit on yB at levels some runs break, and
    a bundle of no OC model that keeps the training runs' peaks (the verdict needs no model)."""
    import numpy as np

    from node.models.bundle import Bundle
    from node.training.fit import load_runs
    from node.training.forecast import peak_table

    d = tmp_path_factory.mktemp("limits")
    chans = ["--channels", "nB,yB,tF", "--plateau-scale", "0.05", "--quiet"]
    assert main(["simulate", "--runs", "4", "--seed", "3", "--out", str(d / "train.mcap"), *chans]) == 0
    assert main(["simulate", "--runs", "6", "--skip", "4", "--seed", "3", "--out", str(d / "test.mcap"),
                 *chans]) == 0
    plain = load_schedule(d / "train.schedule.toml")
    train, test = load_runs([str(d / "train.mcap")], True), load_runs([str(d / "test.mcap")], True)
    peaks = peak_table(train, plain, "yB").peak
    band = float(np.nanmedian(peaks[:, plain.index("OC7"):plain.index("OC10") + 1]))
    limits = (Limit("yB", band, 7000.0, 9900.0), Limit("yB", float(np.nanmedian(peaks[:, 1])), oc="OC3"))
    schedule = Schedule(plain.ocs, plain.switch, plain.tolerance, limits)
    bundle = Bundle("lasso", "yB", schedule, [], forecast=peak_table(train, schedule, "yB"))
    return {"dir": d, "schedule": schedule, "bundle": bundle, "train": train, "test": test}


def _stepped(bundle, runs) -> tuple[list[dict], list[dict], list[float]]:  # noqa: ANN001
    """The monitor and verdict messages of one pipeline stepped over ``runs``, and each monitor
    message's switch speed (held over dropouts, as the node holds it)."""
    import numpy as np

    from node.runtime.align import AlignedSample
    from node.runtime.pipeline import MonitorPipeline
    from node.runtime.runcurve import hold_last

    pipe = MonitorPipeline(bundle)
    msgs, verdicts, speeds = [], [], []
    for run in runs:
        speeds += hold_last(np.asarray(run.column("nB"), float)).tolist()
        for k in range(len(run.t)):
            vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
            msgs.append(pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))[0])
            verdicts += pipe.verdicts
    ended = pipe.end_verdict()
    return msgs, verdicts + ([ended] if ended is not None else []), speeds


def test_every_exceedance_and_no_other_sample_is_over_its_limit(campaign: dict) -> None:
    schedule = campaign["schedule"]
    msgs, _, speeds = _stepped(campaign["bundle"], campaign["test"])
    over = exceed = 0
    for m, speed in zip(msgs, speeds, strict=True):
        assert set(m) >= {"limit", "over_limit"}
        assert m["limit"] == limit_in_force(schedule.limits, speed, m["oc"])
        breaks = m["limit"] is not None and m["measured"] is not None and m["measured"] > m["limit"]
        assert m["over_limit"] is breaks
        over += m["over_limit"]
        exceed += breaks
    assert over == exceed > 0 and sum(m["limit"] is not None for m in msgs) > 10 * over


def test_without_limits_the_fields_are_absent(campaign: dict) -> None:
    from dataclasses import replace

    plain = replace(campaign["bundle"], schedule=replace(campaign["schedule"], limits=()))
    msgs, verdicts, _ = _stepped(plain, campaign["test"][:1])
    assert not verdicts and not any("limit" in m or "over_limit" in m for m in msgs)


def test_a_verdict_at_each_oc_switch_and_at_the_end_of_each_run(campaign: dict) -> None:
    import numpy as np

    schedule = campaign["schedule"]
    ratio = campaign["bundle"].forecast.ratio
    msgs, verdicts, _ = _stepped(campaign["bundle"], campaign["test"])
    switches = [k for k in range(1, len(msgs)) if msgs[k]["oc"] != msgs[k - 1]["oc"]
                and msgs[k]["oc"] is not None]
    ends = [v for v in verdicts if v["status"] != "pending" and not v["forecast"]]
    assert len(ends) == len(campaign["test"])  # one final verdict per run
    assert len(verdicts) == len(switches) + len(ends)
    by_t = {m["t"]: k for k, m in enumerate(msgs)}
    statuses = set()
    for v in verdicts:
        k = by_t[v["t"]]
        run = [m for m in msgs[:k + 1] if m["t"] >= v["run"]]
        assert run[0]["oc"] is not None and msgs[by_t[v["run"]] - 1]["oc"] is None  # the run's start
        gaps = [m["limit"] - m["measured"] if m["limit"] is not None and m["measured"] is not None
                else math.inf for m in run]
        assert v["margin"] == (min(gaps) if min(gaps) < math.inf else None)
        assert v["margin_oc"] == (run[gaps.index(min(gaps))]["oc"] if min(gaps) < math.inf else None)
        failed = any(m["over_limit"] for m in run)
        final = v in ends
        assert v["status"] == ("fail" if failed else "pass" if final else "pending")
        statuses.add(v["status"])
        if final:
            assert v["forecast"] == [] and v["p_fail"] == 0.0
        else:  # the segments from the one just entered to the rundown
            assert [f["oc"] for f in v["forecast"]] == list(schedule.segments[schedule.index(msgs[k]["oc"]):])
            assert 0.0 <= v["p_fail"] <= 1.0
            for f in v["forecast"]:
                assert f["peak_lo"] < f["peak"] < f["peak_hi"]
                limited = bool(np.isfinite(ratio[:, schedule.index(f["oc"])]).any())
                assert (f["p_exceed"] is not None) == limited
    assert "fail" in statuses and "pending" in statuses


def test_the_bundle_keeps_the_limits_and_peaks_and_an_older_one_gives_no_forecast(
        campaign: dict, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import json
    import logging

    import numpy as np

    from node.models.bundle import load_bundle, save_bundle
    from node.runtime.core import NodeCore

    bundle = campaign["bundle"]
    back = load_bundle(save_bundle(bundle, tmp_path / "m"))
    assert back.schedule == bundle.schedule and back.schedule.limits
    np.testing.assert_array_equal(back.forecast.peak, bundle.forecast.peak)
    np.testing.assert_array_equal(back.forecast.ratio, bundle.forecast.ratio)
    assert _stepped(back, campaign["test"][:1])[1] == _stepped(bundle, campaign["test"][:1])[1]
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    for change in ("older", "newer"):
        if change == "older":
            del manifest["forecast"]
        else:
            manifest["forecast"] = {**bundle.forecast.manifest(), "version": 99}
        (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
        old = load_bundle(tmp_path / "m")
        assert old.forecast is None
        _, verdicts, _ = _stepped(old, campaign["test"][:1])
        assert verdicts and all(v["p_fail"] is None and v["forecast"] == [] for v in verdicts)
        with caplog.at_level(logging.WARNING):
            NodeCore(old)
        assert sum("no training peaks for yB" in r.getMessage() for r in caplog.records) == 1
        caplog.clear()
    manifest["forecast"] = {**bundle.forecast.manifest(), "peak": [[-1.0] * len(bundle.schedule.segments)]}
    (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(OrdervibError, match="forecast.peak must be"):
        load_bundle(tmp_path / "m")


def test_the_forecast_recovers_a_known_level_model_and_its_intervals_cover() -> None:
    """Peaks drawn from log peak = mu_s + a_r + e (tau 0.3, sigma 0.1): the fitted variances are
    the model's, and on new runs of it the forecasts after three segments are calibrated: the 90 %
    intervals cover 90 % of the peaks, and p_exceed is as often right as it says."""
    import numpy as np

    from node.models.forecast import Forecaster, PeakTable

    rng = np.random.default_rng(0)
    S, tau, sigma = 8, 0.3, 0.1
    mu = np.log(np.linspace(2.0, 10.0, S))

    def draw(n: int) -> np.ndarray:
        return np.exp(mu + tau * rng.standard_normal((n, 1)) + sigma * rng.standard_normal((n, S)))

    train = draw(600)
    limit = np.quantile(train, 0.7, axis=0)
    f = Forecaster(PeakTable(tuple(f"S{i}" for i in range(S)), train, train / limit))
    assert f.tau2 == pytest.approx(tau ** 2, rel=0.2)
    assert float(np.mean(f.sigma2)) == pytest.approx(sigma ** 2, rel=0.1)
    new = draw(1000)
    covered, p, hit = [], [], []
    for row in new:
        out, p_fail, _ = f.forecast({s: float(row[s]) for s in range(3)}, range(3, S))
        covered += [e["peak_lo"] <= x <= e["peak_hi"] for e, x in zip(out, row[3:])]
        p += [e["p_exceed"] for e in out]
        hit += list(row[3:] > limit[3:])
    assert np.mean(covered) == pytest.approx(0.9, abs=0.02)
    p_arr, hit_arr = np.array(p), np.array(hit, dtype=float)
    brier, climate = np.mean((p_arr - hit_arr) ** 2), np.mean((0.3 - hit_arr) ** 2)
    assert brier < 0.7 * climate  # the run's level, known from three segments, tells
    for lo, hi in ((0.0, 0.2), (0.2, 0.8), (0.8, 1.0)):  # reliability: as often as it says
        sel = (p_arr >= lo) & (p_arr < hi)
        assert abs(hit_arr[sel].mean() - p_arr[sel].mean()) < 0.05
