"""``ordervib report`` with acceptance limits: the page opens with each run's pass-off verdict as
the node gave it (with the engine, bed and date of its recording's ``ordervib`` metadata record),
then the node's forecasts at each OC switch against what then happened; without limits the page
is as it was. Panels I-V are not drawn here (stubbed: ``tests/test_report.py`` checks them)."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
import subprocess

import numpy as np
import pytest

from node.cli import main

PASS, FAIL = (0xC6, 0xEF, 0xC6), (0xF6, 0xC1, 0xB8)  # td.pass, td.fail (replay.report.document.CSS)
ENGINE = {"engine": "E42", "date": "2026-03-01"}  # no bed: the topic's is shown
PANEL_MAKERS = ("context_panel", "parameters_panel", "validation_panel", "prediction_panel",
                "transient_panel")


def _stub_panels(mp: pytest.MonkeyPatch) -> None:
    """Panels I-V as one line each (their figures take most of a report's time)."""
    from replay.report import build
    from replay.report.document import Paragraph

    for name in PANEL_MAKERS:
        mp.setattr(build, name, lambda *a, **k: [Paragraph("not drawn in this test")])


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Four training runs and two held-out ones (nB, yB, tF; short plateaus), a Lasso model
    trained with limits on yB at the training runs' median peaks (a speed band and one OC), the
    held-out recording copied with an ``ordervib`` metadata record, its report, the node's
    verdict messages over it and its runs."""
    from node.contract import load_schedule
    from node.contract.schedule import Limit, Schedule
    from node.mcap import McapWriter, ReadStats, copy_messages, open_recording
    from node.models.bundle import load_model
    from node.training.fit import load_runs
    from node.training.forecast import peak_table
    from replay.offline import replay

    d = tmp_path_factory.mktemp("verdict")
    chans = ["--channels", "nB,yB,tF", "--plateau-scale", "0.05", "--quiet"]
    assert main(["simulate", "--runs", "4", "--seed", "3", "--out", str(d / "train.mcap"), *chans]) == 0
    assert main(["simulate", "--runs", "6", "--skip", "4", "--seed", "3", "--out", str(d / "test.mcap"),
                 *chans]) == 0
    plain = load_schedule(d / "train.schedule.toml")
    peaks = peak_table(load_runs([str(d / "train.mcap")], True), plain, "yB").peak
    band = float(np.nanmedian(peaks[:, plain.index("OC7"):plain.index("OC10") + 1]))
    limits = (Limit("yB", band, 7000.0, 9900.0), Limit("yB", float(np.nanmedian(peaks[:, 1])), oc="OC3"))
    (d / "limits.toml").write_text(Schedule(plain.ocs, plain.switch, plain.tolerance, limits).to_toml())
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "limits.toml"), "--out", str(d / "m"),
                 "--method", "lasso", "--inputs", "nB,tF", "--quiet", "--workers", "1"]) == 0
    tagged = d / "tagged.mcap"
    with open_recording(d / "test.mcap") as rec, open(tagged, "wb") as f:
        writer = McapWriter(f)
        for _ in copy_messages(rec, writer, ReadStats()):
            pass
        writer.add_metadata("ordervib", ENGINE)
        writer.finish()
    with pytest.MonkeyPatch.context() as mp:
        _stub_panels(mp)
        assert main(["report", str(tagged), "--model", str(d / "m"), "--out", str(d / "r.html"),
                     "--quiet"]) == 0
    model = load_model(d / "m")
    return {"dir": d, "tagged": str(tagged), "model": model,
            "html": (d / "r.html").read_text(encoding="utf-8"),
            "verdicts": replay(str(tagged), model, None, workers=0).verdicts,
            "runs": load_runs([str(tagged)], quiet=True)}


def _cells(html: str, caption: str) -> list[list[str]]:
    """The body rows of the table whose caption starts with ``caption`` (cell texts)."""
    table = html[html.index(f"<caption>{caption}"):]
    body = table[table.index("<tbody>"):table.index("</tbody>")]
    return [re.findall(r"<td[^>]*>([^<]*)</td>", row) for row in body.split("</tr>") if "<td" in row]


def test_the_report_opens_with_each_runs_verdict_as_the_node_gave_it(made: dict) -> None:
    from node.mcap import recorded_engine

    html = made["html"]
    ids = re.findall(r'<section id="([^"]+)">', html)
    assert ids[:2] == ["verdict", "summary"] and len(ids) == 7
    verdict = html[html.index('<section id="verdict">'):html.index('<section id="summary">')]
    assert "<details" not in verdict  # open, first
    finals = [m for _, m in made["verdicts"] if m["status"] != "pending" and not m["forecast"]]
    rows = _cells(verdict, "yB: each run")
    assert len(rows) == len(finals) == len(made["runs"]) == 2
    for i, (row, m) in enumerate(zip(rows, finals, strict=True)):
        assert row[:5] == [f"tagged #{i + 1}", "E42", "bed1", "2026-03-01", m["status"]]
        assert row[5] == f"{m['margin']:.3f}" and row[6] == m["margin_oc"]
    assert {m["status"] for m in finals} == {"pass", "fail"}  # the limits sit among the runs' peaks
    worst = min(finals, key=lambda m: m["margin"])
    assert f"<h3>yB: 1 of 2 runs FAIL, smallest margin {worst['margin']:.3f} mm/s in " \
           f"{worst['margin_oc']} (" in verdict
    assert "Limits on yB: 7000-9900 rpm: " in verdict and "oc OC3: " in verdict
    assert recorded_engine(made["tagged"]) == ENGINE
    assert recorded_engine(str(made["dir"] / "test.mcap")) == {}


def test_each_forecast_is_set_against_the_nodes_own_samples(made: dict) -> None:
    """The report's measured peak and exceedance of each forecast segment are those of the node's
    monitor messages in that run and segment (their measured values and ``over_limit``); the
    reliability table counts every scored forecast, its observed share theirs."""
    from conftest import node_messages

    from node.models.bundle import Bundle
    from replay.report.panels import RunSet
    from replay.report.verdict import outcomes, reliability, run_verdicts

    bundle, runs = made["model"]["yB"], made["runs"]
    labels = [RunSet.label(made["tagged"], i) for i in range(len(runs))]
    mine = run_verdicts(made["verdicts"], RunSet(runs, labels), "yB")
    assert [v.run for v in mine] == [0, 1]
    found = outcomes(mine, RunSet(runs, labels), bundle.schedule, bundle, "yB")
    bare = Bundle(bundle.method, "yB", bundle.schedule, [], forecast=bundle.forecast)  # (no prediction)
    peak: dict[tuple[str, str], float] = {}
    over: dict[tuple[str, str], bool] = {}
    for label, run in zip(labels, runs, strict=True):
        for m in node_messages(bare, [run]):
            if m["oc"] is not None and m["measured"] is not None:
                k = (label, m["oc"])
                peak[k] = max(peak.get(k, -math.inf), m["measured"])
                over[k] = over.get(k, False) or m["over_limit"]
    assert len(found) > 20
    for o in found:
        k = (o.run, o.oc)
        assert o.measured == pytest.approx(peak[k], abs=1e-9) and o.exceeded == over[k]
        assert o.lo < o.peak < o.hi and 0.0 <= o.p_exceed <= 1.0 and 0.0 <= o.climatology <= 1.0
    assert {o.exceeded for o in found} == {True, False}
    p = np.array([o.p_exceed for o in found])
    hit = np.array([float(o.exceeded) for o in found])
    bins = reliability(p, hit)
    assert sum(b[2] for b in bins) == len(found)
    assert sum(b[2] * b[4] for b in bins) == pytest.approx(hit.sum())
    page = _cells(made["html"], "yB: reliability of p_exceed")
    assert [(int(r[1]), float(r[3])) for r in page] == [(b[2], round(b[4], 2)) for b in bins]
    assert f"Brier score {np.mean((p - hit) ** 2):.3f} over {len(found)} forecasts" in made["html"]


def test_without_limits_the_page_is_as_it_was(made: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same runs with the model's limits taken away: no verdict section, the rest of the page
    byte for byte the page with limits less its verdict section (and its link)."""
    from node.mcap import recorded_engine
    from node.models.bundle import Model
    from node.training.fit import load_runs
    from replay.offline import node_alarms
    from replay.report.build import build_report
    from replay.report.panels import RunSet

    _stub_panels(monkeypatch)
    model = made["model"]
    plain = Model(tuple(dataclasses.replace(b, schedule=dataclasses.replace(b.schedule, limits=()))
                        for b in model.bundles))
    recs = [str(made["dir"] / "test.mcap")]  # (no metadata record: engine and date unknown)
    runs = load_runs(recs, quiet=True)
    rs = RunSet(runs, [RunSet.label(recs[0], i) for i in range(len(runs))], None,
                [recorded_engine(recs[0])] * len(runs))
    pages = {}
    for name, m in (("limits", model), ("plain", plain)):
        alarms = node_alarms(recs, m, workers=0, carry=True)
        assert bool(alarms.verdicts) == (name == "limits")
        pages[name] = build_report(m, rs, recs, ["yB"], "m", alarms=alarms)
    with_limits = pages["limits"]
    assert [r[1:4] for r in _cells(with_limits, "yB: each run")] == [["unknown", "bed1", "unknown"]] * 2
    start = with_limits.index('<section id="verdict">')
    cut = with_limits[:start] + with_limits[with_limits.index('<section id="summary">'):]
    cut = cut.replace('<a href="#verdict">Pass-off verdict</a> ', "")
    assert '<section id="verdict">' not in pages["plain"] and cut == pages["plain"]


def test_the_first_screen_shows_the_verdict_in_headless_chromium(made: dict) -> None:
    """In a 1280 x 900 window, the verdict's pass and fail cells (their own colours) are drawn
    on the first screen, and the page's first section is the verdict."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("no chromium on this machine")
    d = made["dir"]
    out = d / "r.html"
    base = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            f"--user-data-dir={d / 'chromium'}"]
    dom = subprocess.run([*base, "--dump-dom", out.as_uri()], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    assert re.findall(r'<section id="([^"]+)">', dom)[:2] == ["verdict", "summary"]
    shot = d / "first.png"
    subprocess.run([*base, "--window-size=1280,900", f"--screenshot={shot}", out.as_uri()],
                   capture_output=True, timeout=60, check=True)
    from PIL import Image

    with Image.open(shot) as im:
        rgb = np.asarray(im.convert("RGB")).reshape(-1, 3)
    for colour in (PASS, FAIL):  # the verdict cells' own colours
        assert (np.abs(rgb.astype(int) - colour).max(axis=1) <= 2).sum() > 200, colour
