"""``ordervib predict`` with acceptance limits: per planned OC the predicted peak and the
probability that it exceeds its limit (the prediction's 90 % interval read as a normal), in the
table, in ``--json`` and in the CSV (``yB_limit``, ``yB_p_exceed``); without limits the output is
as it was."""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import pytest
from scipy.special import ndtr

from node.cli import main
from node.contract import load_schedule
from node.contract.schedule import Limit, Schedule, limit_in_force

Z90 = 1.6448536269514722  # the normal's 95th percentile


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Three short simulated runs, a Lasso model of yB on the speed, and its prediction of the
    schedule's plateaus (5 s each) with no limit: the CSV and the text."""
    d = tmp_path_factory.mktemp("predict_limits")
    assert main(["simulate", "--runs", "3", "--seed", "4", "--out", str(d / "train.mcap"), "--channels",
                 "nB,yB,tF,tH,tI", "--plateau-scale", "0.05", "--quiet"]) == 0
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(d / "m"), "--method", "lasso", "--inputs", "nB", "--no-curve-candidates",
                 "--target", "yB", "--quiet", "--workers", "1"]) == 0
    schedule = d / "train.schedule.toml"
    return {"dir": d, "schedule": schedule, **_predict(d, schedule, "plain")}


def _predict(d: Path, profile: Path, name: str, model: str = "m", as_json: bool = False) -> dict:
    """The prediction of ``profile``: its CSV's text and stdout (text, or JSON), its status."""
    from contextlib import redirect_stdout

    path = d / f"{name}.csv"
    buf = io.StringIO()
    with redirect_stdout(buf):
        status = main(["predict", "--model", str(d / model), "--profile", str(profile), "--plateau-s", "5",
                       "--quiet", "--out", str(path), *(["--json"] if as_json else [])])
    assert status in (0, 3)  # (3: the short plateaus' plan goes past the training runs' top speed)
    return {"csv": path.read_text(), "text": buf.getvalue(), "status": status}


def _rows(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(line for line in text.splitlines() if not line.startswith("# ")))


def _peaks(made: dict) -> dict[str, float]:
    peak: dict[str, float] = {}
    for r in _rows(made["csv"]):
        if r["oc"] and r["yB"]:
            peak[r["oc"]] = max(peak.get(r["oc"], 0.0), float(r["yB"]))
    return peak


def test_a_peak_far_above_its_limit_is_near_certain_far_below_near_impossible(made: dict) -> None:
    """OC7's limit a hundredth of its predicted peak, OC3's ten times its peak, a speed band over
    OC10's speed at its peak: p_exceed near 1, near 0 and one half; every row of the CSV holds the
    limit in force by the node's rule and its p_exceed, that of the normal about the prediction
    with the interval's upper end its 95th percentile."""
    d, peak = made["dir"], _peaks(made)
    plain = load_schedule(made["schedule"])
    s10 = plain.ocs[plain.index("OC10")].speed
    limits = (Limit("yB", peak["OC7"] / 100, oc="OC7"), Limit("yB", peak["OC3"] * 10, oc="OC3"),
              Limit("yB", peak["OC10"], s10 - 50.0, s10 + 50.0))
    path = d / "limits.toml"
    path.write_text(Schedule(plain.ocs, plain.switch, plain.tolerance, limits).to_toml())
    got = _predict(d, path, "limits", as_json=True)
    assert got["status"] == made["status"]
    table = {r["OC"]: r for r in json.loads(got["text"])["limits"]}
    assert set(table) == set(peak)
    assert table["OC7"]["p_exceed"] > 0.99 and table["OC3"]["p_exceed"] < 1e-4
    assert table["OC10"]["p_exceed"] == pytest.approx(0.5, abs=1e-3)  # its peak at the limit
    assert table["OC7"]["limit"] == pytest.approx(peak["OC7"] / 100, rel=1e-5)
    assert all(table[oc]["limit"] is None and table[oc]["p_exceed"] is None for oc in ("OC2a", "OC13"))
    assert table["OC7"]["peak"] == pytest.approx(peak["OC7"], abs=1e-3)
    rows = _rows(got["csv"])
    assert list(rows[0])[4:10] == ["yB", "yB_lo", "yB_hi", "yB_envelope", "yB_limit", "yB_p_exceed"]
    edges = (s10 - 50.0, s10 + 50.0)
    for r in rows:
        if min(abs(float(r["nB"]) - e) for e in edges) < 0.05:
            continue  # (the CSV's 6 digits of the speed may cross a band's edge)
        lim = limit_in_force(limits, float(r["nB"]), r["oc"] or None)
        assert (r["yB_limit"] == "") == (lim is None)
        assert (r["yB_p_exceed"] == "") == (lim is None or not r["yB"])
        if r["yB_p_exceed"]:
            y, hi = float(r["yB"]), float(r["yB_hi"])
            assert float(r["yB_limit"]) == pytest.approx(lim, rel=1e-5)
            want = ndtr((y - lim) * Z90 / (hi - y)) if hi > y else float(y > lim)
            assert float(r["yB_p_exceed"]) == pytest.approx(want, abs=2e-5)
    # less the two columns and the limits note, the CSV is the one without limits, byte for byte
    lines = [line for line in got["csv"].splitlines(keepends=True) if not line.startswith("# limits: ")]
    body = [line for line in lines if not line.startswith("# ")]
    cut = io.StringIO()
    w = csv.writer(cut, lineterminator="\n")
    for row in csv.reader(body):
        w.writerow(row[:8] + row[10:])
    assert "".join(line for line in lines if line.startswith("# ")) + cut.getvalue() == made["csv"]


def test_without_limits_the_output_has_no_limit_part(made: dict) -> None:
    text = made["text"].replace(str(made["dir"]), "")  # (its folder's name holds the word)
    assert "OC7" in text and "limit" not in text and "p_exceed" not in text
    assert "limit" not in made["csv"]


def test_the_models_own_limits_hold_a_csv_plan_and_a_foreign_target_is_refused(
        made: dict, capsys: pytest.CaptureFixture[str]) -> None:
    """A plan as CSV takes the limits of the model's schedule; a schedule given with a limit on
    a target the model lacks is a one-line error."""
    d, peak = made["dir"], _peaks(made)
    shutil.copytree(d / "m", d / "lm")
    manifest = json.loads((d / "lm" / "manifest.json").read_text())
    manifest["schedule"]["limit"] = [{"target": "yB", "max": peak["OC7"] / 100, "oc": "OC7"}]
    (d / "lm" / "manifest.json").write_text(json.dumps(manifest))
    plan = d / "plan.csv"
    rows = _rows(made["csv"])[::40]
    plan.write_text("t,nB\n" + "".join(f"{r['t']},{r['nB']}\n" for r in rows))
    got = _predict(d, plan, "own", model="lm", as_json=True)
    table = {r["OC"]: r for r in json.loads(got["text"])["limits"]}
    assert table["OC7"]["p_exceed"] > 0.99 and table["OC3"]["limit"] is None
    bad = d / "bad.toml"
    bad.write_text(made["schedule"].read_text() + '\n[[limit]]\ntarget = "yA"\nmax = 3.0\n')
    capsys.readouterr()
    assert main(["predict", "--model", str(d / "m"), "--profile", str(bad), "--out", str(d / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "[[limit]] on yA, which the model does not hold" in err and "\n" not in err
    assert not (d / "x.csv").exists()
