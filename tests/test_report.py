"""``ordervib report``: the committed recordings' report opens with its summary, then its four
panels folded, renders in a browser with readable figures, says in-sample or held-out as the
model's training runs say, and bad inputs leave no file."""

from __future__ import annotations

import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest
from conftest import small_campaign

from node.cli import main
from replay.report.build import PANELS, SUMMARY
from replay.report.document import MIN_TEXT_PX

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = [str(ROOT / "recordings" / "engine1_runs.mcap"), str(ROOT / "recordings" / "engine1_fault.mcap")]


class _Panels(HTMLParser):
    """Sections by id: their h2 heading, their image count, whether they are folded (their
    content in a closed ``<details>``, the h2 in its ``<summary>``); every src and href seen;
    each image's smallest text as the page shows it (``data-text-px``)."""

    def __init__(self) -> None:
        super().__init__()
        self.sections: dict[str, dict] = {}
        self.current: str | None = None
        self.in_h2 = False
        self.in_summary = False
        self.links: list[str] = []
        self.text_px: list[float] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.links += [v for k, v in attrs if k in ("src", "href") and v is not None]
        if tag == "section":
            self.current = a.get("id")
            self.sections[self.current or ""] = {"title": "", "images": 0, "folded": False}
        elif tag == "details" and self.current:
            self.sections[self.current]["folded"] = "open" not in a
        elif tag == "summary":
            self.in_summary = True
        elif tag == "h2" and self.current:
            self.in_h2 = True
            if self.sections[self.current]["folded"] and not self.in_summary:
                self.sections[self.current]["folded"] = False  # a title outside the summary line
        elif tag == "img" and self.current and (a.get("src") or "").startswith("data:image/png;base64,"):
            self.sections[self.current]["images"] += 1
            self.text_px.append(float(a.get("data-text-px") or "nan"))

    def handle_endtag(self, tag: str) -> None:
        if tag == "summary":
            self.in_summary = False
        elif tag == "h2":
            self.in_h2 = False
        elif tag == "section":
            self.current = None

    def handle_data(self, data: str) -> None:
        if self.in_h2 and self.current:
            self.sections[self.current]["title"] += data


def _panels(html: str) -> _Panels:
    p = _Panels()
    p.feed(html)
    return p


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A small model (conftest's campaign: Lasso of yB on nB, tF) and the report of the committed
    recordings with it."""
    d = small_campaign(tmp_path_factory.mktemp("report"), 5)
    out = d / "report.html"
    assert main(["report", *RECORDINGS, "--model", str(d / "m"), "--out", str(out), "--quiet"]) == 0
    return d, out


SECTIONS = [SUMMARY[0], *(pid for pid, _ in PANELS)]  # the summary first, open; the panels folded


def test_report_has_a_summary_then_four_folded_panels_each_with_a_figure_and_nothing_external(
        made: tuple[Path, Path]) -> None:
    _, out = made
    html = out.read_text(encoding="utf-8")
    p = _panels(html)
    assert list(p.sections) == SECTIONS
    assert p.sections[SUMMARY[0]]["title"] == SUMMARY[1] and not p.sections[SUMMARY[0]]["folded"]
    for (pid, title), numeral in zip(PANELS, ("I.", "II.", "III.", "IV.", "V."), strict=True):
        assert p.sections[pid]["title"] == title and title.startswith(numeral + " ")
        assert p.sections[pid]["images"] >= 1, pid
        assert p.sections[pid]["folded"], pid
    assert len(p.text_px) >= 8 and min(p.text_px) >= MIN_TEXT_PX  # every figure's text readable
    summary = html[html.index('id="summary"'):html.index('id="panel-context"')]
    assert "<h3>yB: " in summary and "held-out runs (5)" in summary and "in-sample" not in summary
    assert "Held-out runs (engine1_runs #1, engine1_runs #2, engine1_runs #3, engine1_runs #4 and 1 more)" \
        in summary
    assert all(link.startswith(("data:", "#")) for link in p.links)  # no server, no network
    assert "http://" not in html and "https://" not in html and "<script" not in html
    assert "engine1_fault #1" in html and "OC10" in html  # the runs and OCs are named
    val = html[html.index('id="panel-validation"'):html.index('id="panel-prediction"')]
    assert "Held-out runs (not among the model&#x27;s training runs): engine1_runs #1" in val
    assert "held-out eps_td" in val and "in-sample" not in val  # the model was trained on other runs
    assert "outside the envelope" in val and " %</td>" in val  # each OC's share beyond the envelope
    assert "pending" not in html
    ctx = html[html.index('id="panel-context"'):html.index('id="panel-parameters"')]
    assert "Contextual characteristic curves" in ctx
    assert ctx.count("<img") >= 4  # the curve, the clusters' timeline, the clusters, the violins
    pred = html[html.index('id="panel-prediction"'):]
    assert "A planned pass-off" in pred and pred.count("<img") >= 3  # a run, the plan, figure A.5
    assert "<td>engine1_fault #1</td><td>held-out</td>" in pred and "<td>held-out runs</td>" in pred
    assert "<td>curve, held-out runs</td>" in pred
    assert "in-sample" not in pred.replace("held-out or in-sample", "")


def test_report_renders_in_headless_chromium(made: tuple[Path, Path]) -> None:
    chromium = shutil.which("chromium")
    if chromium is None:
        pytest.skip("no chromium on this machine")
    d, out = made
    base = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            f"--user-data-dir={d / 'chromium'}"]
    dom = subprocess.run([*base, "--dump-dom", out.as_uri()], capture_output=True, text=True,
                         timeout=60, check=True).stdout
    p = _panels(dom)
    assert list(p.sections) == SECTIONS
    assert all(p.sections[pid]["images"] >= 1 and p.sections[pid]["folded"] for pid, _ in PANELS)
    shot = d / "shot.png"
    subprocess.run([*base, "--window-size=1280,3000", f"--screenshot={shot}", out.as_uri()],
                   capture_output=True, timeout=60, check=True)
    import numpy as np
    from PIL import Image
    with Image.open(shot) as im:
        assert im.size == (1280, 3000)
        grey = np.asarray(im.convert("L"))
        colours = im.convert("RGB").crop((0, 0, 1280, 1000)).resize((128, 100)).getcolors(maxcolors=128 * 100)
    assert colours is not None and len(colours) > 20  # the first screen: text and tables, not blank
    drawn = np.flatnonzero((grey < 250).any(axis=1))
    assert 600 < drawn[-1] < 1300  # the summary and the four folded panels' lines: about one screen


def _summary_of(d: Path, recordings: list[Path]) -> str:
    """The summary's HTML of ``recordings`` with the model ``d/m``, read as ``ordervib report``
    reads them (each run with its recording's sha256), no alarm replayed."""
    from node.models.bundle import load_model
    from node.training.fit import read_sourced
    from replay.offline import NodeAlarms
    from replay.report.build import summary_panel
    from replay.report.panels import RunSet

    runs, labels, hashes = [], [], []
    for rec in recordings:
        found, read, _ = read_sourced([str(rec)], True)
        runs += found
        labels += [RunSet.label(str(rec), i) for i in range(len(found))]
        hashes += [read[0]["sha256"]] * len(found)
    panel, _ = summary_panel(load_model(d / "m"), RunSet(runs, labels, hashes), ["yB"], NodeAlarms([], 0))
    return panel.html()


def test_the_summary_says_in_sample_for_the_training_recording_and_held_out_for_another(
        made: tuple[Path, Path]) -> None:
    """The model was trained on train.mcap (2 runs): they are in-sample, test.mcap's run held out;
    each OC of the model is named with its kind, and the held-out numbers are those of the
    held-out run alone (as ``ordervib evaluate test.mcap`` scores it)."""
    import re

    import numpy as np

    from node.models.bundle import load_bundle
    from node.training.evaluation import predict_segments, score_segments
    from node.training.fit import load_runs

    d, _ = made
    html = _summary_of(d, [d / "train.mcap", d / "test.mcap"])
    assert html.index("<h2>Summary</h2>") < html.index("<h3>yB: ") < html.index("<table>")
    assert '<th colspan="2">held-out runs (1)</th><th colspan="2">in-sample runs (2)</th>' in html
    assert "Held-out runs (test #1): " in html and "In-sample runs (train #1, train #2): " in html
    cells = re.findall(r"<tr><td>(OC\w+|rundown)</td><td>([^<]*)</td><td[^>]*>([^<]*)</td>", html)
    rows = {m[0]: m[1:] for m in cells}  # OC: (model kind, held-out model eps_td)
    b = load_bundle(d / "m")
    trained = [r for r in b.ocs if r.model is not None and r.name in b.schedule.segments]
    assert trained and all(rows[r.name][0] == r.kind for r in trained)
    test = load_runs([str(d / "test.mcap")], quiet=True)
    alone = score_segments(b.ocs, b.schedule, predict_segments(b.ocs, test, b.schedule, "yB", b.curve,
                                                                 b.config))
    for e in (e for e in alone if np.isfinite(e.eps)):
        assert rows[e.name][1] == f"{e.eps:.3f}", e.name

    only = _summary_of(d, [d / "train.mcap"])  # no held-out run: said so, and no held-out column
    assert "<h3>yB: no held-out run, the errors below are in-sample" in only
    assert "held-out runs (" not in only and "in-sample runs (2)" in only


def test_a_figure_wider_than_the_page_shows_its_text_smaller_and_is_flagged(
        caplog: pytest.LogCaptureFixture) -> None:
    """The page shows a PNG wider than PAGE_WIDTH_PX scaled down: 9 pt at 90 dpi is 11.25 px in a
    10-inch figure (about 900 px), 11.25 x 1080 / its width in a 20-inch one (its PNG some
    1500 px once trimmed), under 11: logged."""
    import base64
    import re

    from matplotlib.figure import Figure

    from replay.report.document import PAGE_WIDTH_PX, figure_html

    shown = {}
    for width in (10.0, 20.0):
        fig = Figure(figsize=(width, 2.0))
        ax = fig.subplots()
        ax.plot([0, 1], [0, 1])
        ax.tick_params(labelsize=9)
        ax.set_xlabel("x", fontsize=9)
        ax.set_ylabel("y", fontsize=9)
        caplog.clear()
        html = figure_html(fig, f"w{width:g}")
        png = base64.b64decode(html[html.index("base64,") + 7:html.rindex('"')])
        px = int.from_bytes(png[16:20], "big")  # the PNG's width
        shown[width] = float(re.search(r'data-text-px="([^"]+)"', html).group(1))
        assert shown[width] == pytest.approx(9 * 90 / 72 * min(1.0, PAGE_WIDTH_PX / px), abs=0.05)
        assert ("smallest text shows at" in caplog.text) == (width == 20.0)
    assert shown[10.0] == pytest.approx(11.25) and shown[20.0] < MIN_TEXT_PX


def _one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err, err


@pytest.mark.parametrize("case, message", [
    ("missing recording", "no-such.mcap"),
    ("not a model", "not an ordervib model bundle"),
    ("missing folder", "output directory does not exist"),
    ("wrong suffix", "must name a .html file"),
    ("unknown target", "the model's targets are yB"),
])
def test_bad_inputs_are_one_line_and_leave_no_file(made: tuple[Path, Path], tmp_path: Path, case: str,
                                                   message: str, capsys: pytest.CaptureFixture[str]) -> None:
    d, _ = made
    model, out, recs, extra = str(d / "m"), tmp_path / "r.html", list(RECORDINGS), []
    if case == "missing recording":
        recs.append(str(tmp_path / "no-such.mcap"))
    elif case == "not a model":
        (tmp_path / "folder").mkdir()
        (tmp_path / "folder" / "notes.txt").write_text("x")
        model = str(tmp_path / "folder")
    elif case == "missing folder":
        out = tmp_path / "nowhere" / "r.html"
    elif case == "wrong suffix":
        out = tmp_path / "r.pdf"
    else:
        extra = ["--target", "yA"]
    before = sorted(p.name for p in tmp_path.iterdir())
    _one_line_error(capsys, ["report", *recs, "--model", model, "--out", str(out), *extra], message)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == before


def test_output_that_is_an_input_is_refused_and_left_as_it_was(made: tuple[Path, Path], tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    d, _ = made
    rec = tmp_path / "rec.html"  # a recording under a name the report could take
    shutil.copy(d / "test.mcap", rec)
    data = rec.read_bytes()
    _one_line_error(capsys, ["report", str(rec), "--model", str(d / "m"), "--out", str(rec)],
                    "must differ from the input")
    assert rec.read_bytes() == data and sorted(p.name for p in tmp_path.iterdir()) == ["rec.html"]


def test_several_targets_give_a_part_per_target_in_every_panel(made: tuple[Path, Path]) -> None:
    """A format-3 model of two targets (here the same per-OC models, named for yA and yB): each
    panel holds a part per target, in the order asked."""
    import dataclasses

    from node.models.bundle import Model, load_bundle
    from node.training.fit import load_runs
    from replay.offline import NodeAlarms
    from replay.report.build import build_report
    from replay.report.panels import RunSet

    d, _ = made
    b = load_bundle(d / "m")
    model = Model((dataclasses.replace(b, target="yA"), b))
    runs = load_runs([RECORDINGS[1]], quiet=True)
    page = build_report(model, RunSet(runs, [RunSet.label(RECORDINGS[1], 0)]), RECORDINGS[1:],
                        ["yB", "yA"], "m", alarms=NodeAlarms([], 0))
    p = _panels(page)
    assert list(p.sections) == SECTIONS
    summary = page[:page.index('<section id="panel-context">')]
    assert 0 < summary.index("<h3>yB: ") < summary.index("<h3>yA: ")
    for pid, _ in PANELS:
        body = page[page.index(f'<section id="{pid}">'):]
        body = body[:body.index("</section>")]
        assert 0 < body.index("<h3>target yB</h3>") < body.index("<h3>target yA</h3>")
        assert p.sections[pid]["images"] >= 2


def test_the_node_carries_the_engine_history_from_one_recording_to_the_next(made: tuple[Path, Path],
                                                                           tmp_path: Path) -> None:
    """Panels II-IV derive one engine's history through all the recordings; the alarms' replay
    (``node_alarms(carry=True)``) hands each recording the engine state the previous one ended
    with, so the node predicts what the report's evaluation predicts (a cold start would not)."""
    import json

    import numpy as np
    from mcap.reader import make_reader

    from node.contract import monitor_key
    from node.models.bundle import load_model
    from node.training.evaluation import predict_segments
    from node.training.fit import load_runs
    from replay.offline import node_alarms, replay

    d, _ = made
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(tmp_path / "mh"), "--method", "lasso", "--inputs", "nB,hist_shutdown,hist_energy",
                 "--no-curve-candidates", "--history", "--quiet", "--workers", "1"]) == 0
    model = load_model(tmp_path / "mh")
    b = model.bundles[0]
    recs = [str(d / "train.mcap"), str(d / "test.mcap")]
    runs = load_runs(recs, quiet=True)
    want = [p for p in predict_segments(b.ocs, runs, b.schedule, b.target, b.curve, b.config)
            if p.run == len(runs) - 1]
    first = replay(recs[0], model, None, workers=0)
    gap = {}
    for engines in (None, first.engines):
        out = tmp_path / "node.mcap"
        replay(recs[1], model, str(out), workers=0, engines=engines)
        with open(out, "rb") as f:
            node = {round(json.loads(m.data)["t"], 6): json.loads(m.data)["predicted"]
                    for _, _, m in make_reader(f).iter_messages(topics=[monitor_key(runs[-1].bed, b.target)])}
        got = np.array([node[round(float(t), 6)] for p in want for t in p.t], float)
        gap[engines is None] = float(np.max(np.abs(got - np.concatenate([p.predicted for p in want]))))
    assert gap[False] < 1e-9 < gap[True]  # carried: the report's numbers; cold: others
    assert node_alarms(recs, model, workers=0, carry=True).carried
