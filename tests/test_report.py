"""``ordervib report``: the committed recordings' report has its four panels, renders in a
browser, and bad inputs leave no file."""

from __future__ import annotations

import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest
from conftest import small_campaign

from node.cli import main
from replay.report.build import PANELS

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = [str(ROOT / "recordings" / "engine1_runs.mcap"), str(ROOT / "recordings" / "engine1_fault.mcap")]


class _Panels(HTMLParser):
    """Sections by id: their h2 heading, their image count; every src and href seen."""

    def __init__(self) -> None:
        super().__init__()
        self.sections: dict[str, dict] = {}
        self.current: str | None = None
        self.in_h2 = False
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.links += [v for k, v in attrs if k in ("src", "href") and v is not None]
        if tag == "section":
            self.current = a.get("id")
            self.sections[self.current or ""] = {"title": "", "images": 0}
        elif tag == "h2" and self.current:
            self.in_h2 = True
        elif tag == "img" and self.current and (a.get("src") or "").startswith("data:image/png;base64,"):
            self.sections[self.current]["images"] += 1

    def handle_endtag(self, tag: str) -> None:
        if tag == "h2":
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


def test_report_has_four_panels_each_with_a_figure_and_nothing_external(made: tuple[Path, Path]) -> None:
    _, out = made
    html = out.read_text(encoding="utf-8")
    p = _panels(html)
    assert list(p.sections) == [pid for pid, _ in PANELS]
    for (pid, title), numeral in zip(PANELS, ("I.", "II.", "III.", "IV.")):
        assert p.sections[pid]["title"] == title and title.startswith(numeral + " ")
        assert p.sections[pid]["images"] >= 1, pid
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
    assert [pid for pid in p.sections] == [pid for pid, _ in PANELS]
    assert all(s["images"] >= 1 for s in p.sections.values())
    shot = d / "shot.png"
    subprocess.run([*base, "--window-size=1200,1600", f"--screenshot={shot}", out.as_uri()],
                   capture_output=True, timeout=60, check=True)
    from PIL import Image
    with Image.open(shot) as im:
        assert im.size == (1200, 1600)
        colours = im.convert("RGB").resize((120, 160)).getcolors(maxcolors=120 * 160)
    assert colours is not None and len(colours) > 20  # text and plots, not a blank page


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
    assert list(p.sections) == [pid for pid, _ in PANELS]
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
