"""Honest words (issue 30, item 5): ``evaluate`` and ``report`` call a run in-sample when it is
among the model's training runs (its span, or its recording's sha256), held-out only otherwise,
and unknown when an older model's record cannot tell."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from node.cli import main
from node.mcap import ReadStats
from node.models.bundle import Bundle, load_bundle
from node.training.runs import Run, read_runs

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "recordings" / "engine1_runs.mcap"
FAULT = ROOT / "recordings" / "engine1_fault.mcap"
SCHEDULE = ROOT / "recordings" / "engine1_runs.schedule.toml"
CHEAP = ["--method", "lasso", "--inputs", "nB,tF", "--target", "yB", "--no-curve-candidates", "--no-prom",
         "--quiet", "--workers", "1"]


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cheap model of yB (lasso on nB, tF) trained on the four runs of engine1_runs.mcap."""
    out = tmp_path_factory.mktemp("honest") / "m"
    assert main(["train", str(RUNS), "--schedule", str(SCHEDULE), "--out", str(out), *CHEAP]) == 0
    return out


def _read(path: Path) -> tuple[list[Run], str | None]:
    stats = ReadStats()
    runs = read_runs(str(path), stats=stats, sha256=True)
    return runs, stats.sha256


@pytest.fixture(scope="module")
def recorded() -> dict[str, tuple[list[Run], str | None]]:
    """The committed recordings' runs and sha256, by name."""
    return {"runs": _read(RUNS), "fault": _read(FAULT)}


def _without_spans(bundle: Bundle) -> Bundle:
    """The bundle as an ordervib before issue 30 wrote it: its training recordings, no run spans."""
    kept = {k: v for k, v in bundle.training.items() if k != "run_spans"}
    return dataclasses.replace(bundle, training=kept)


def test_the_bundle_records_its_training_runs_spans(model: Path, recorded: dict) -> None:
    training = json.loads((model / "manifest.json").read_text())["training"]
    runs, sha = recorded["runs"]
    assert training["runs"] == 4 and [r["sha256"] for r in training["recordings"]] == [sha]
    assert training["run_spans"] == [[r.bed, float(r.t[0]), float(r.t[-1])] for r in runs]


def test_an_update_spans_the_kept_runs_first_then_the_new(model: Path, tmp_path: Path,
                                                          recorded: dict) -> None:
    out = tmp_path / "m2"
    assert main(["train", "--update", str(model), str(FAULT), "--out", str(out), "--quiet",
                 "--workers", "1"]) == 0
    from node.training.provenance import HELD_OUT, IN_SAMPLE, run_provenance

    old, new = load_bundle(model), load_bundle(out)
    assert new.training["run_spans"][:4] == old.training["run_spans"] and len(new.training["run_spans"]) == 5
    fault = recorded["fault"][0]
    assert run_provenance(old, fault) == [HELD_OUT] and run_provenance(new, fault) == [IN_SAMPLE]


def test_runs_are_told_by_their_span_or_their_recordings_hash(model: Path, recorded: dict) -> None:
    from node.training.provenance import HELD_OUT, IN_SAMPLE, SPAN_TOLERANCE, UNKNOWN, run_provenance

    bundle = load_bundle(model)
    (runs, sha), (fault, fault_sha) = recorded["runs"], recorded["fault"]
    assert run_provenance(bundle, runs) == [IN_SAMPLE] * 4
    assert run_provenance(bundle, fault, [fault_sha]) == [HELD_OUT]
    first = runs[0]  # the same run found in another file (e.g. a node's recording of a replay):
    elsewhere = dataclasses.replace(first, t=first.t + 0.4 * SPAN_TOLERANCE)  # slots read a bit off
    later = dataclasses.replace(first, t=first.t + 1 / 40)  # a sample later: another run
    other_bed = dataclasses.replace(first, bed="bed2")
    cut = dataclasses.replace(first, t=first.t[:-40], data=first.data[:-40])  # a second shorter
    assert run_provenance(bundle, [elsewhere, later, other_bed, cut], ["x"] * 4) == [
        IN_SAMPLE, HELD_OUT, HELD_OUT, HELD_OUT]
    old = _without_spans(bundle)  # an older model: its recordings' hashes tell, nothing else
    assert run_provenance(old, runs, [sha] * 4) == [IN_SAMPLE] * 4
    assert run_provenance(old, [*runs, *fault]) == [UNKNOWN] * 5
    assert run_provenance(old, fault, [fault_sha]) == [UNKNOWN]
    assert run_provenance(dataclasses.replace(bundle, training={}), runs[:1]) == [UNKNOWN]
    with pytest.raises(ValueError, match="1 hashes for 4 runs"):
        run_provenance(bundle, runs, [sha])


def _evaluate(model: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *recs: Path) -> str:
    assert main(["evaluate", str(model), *map(str, recs), "--quiet", "--png", str(tmp_path / "e.png")]) == 0
    return capsys.readouterr().out


def test_evaluate_on_the_training_recording_says_in_sample(model: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    text = _evaluate(model, tmp_path, capsys, RUNS)
    lines = text.splitlines()
    assert f"{RUNS}: 4 run(s), 4 in-sample" in lines
    assert "in-sample runs: 4 of 4 (among the model's training runs)" in lines
    assert any(ln.split()[:4] == ["OC", "model", "segments", "in-sample"] for ln in lines)
    assert any(ln.startswith("mean in-sample eps_td ") for ln in lines)
    assert any(ln.startswith("none of the 4 run(s) is held out") for ln in lines)
    assert "held-out" not in text


def test_evaluate_on_a_later_run_says_held_out(model: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    text = _evaluate(model, tmp_path, capsys, FAULT)
    lines = text.splitlines()
    assert f"{FAULT}: 1 run(s), 1 held-out" in lines and "held-out runs: 1 of 1" in lines
    assert any(ln.startswith("mean held-out eps_td ") for ln in lines)
    assert "in-sample" not in text and "is held out" not in text


def test_evaluate_of_an_older_model_says_unknown_for_other_files(model: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    old = tmp_path / "old"
    manifest = json.loads((model / "manifest.json").read_text())
    del manifest["training"]["run_spans"]
    old.mkdir()
    for f in model.iterdir():
        if f.is_file():
            (old / f.name).write_bytes(f.read_bytes())
    (old / "manifest.json").write_text(json.dumps(manifest))
    text = _evaluate(old, tmp_path, capsys, FAULT)
    lines = text.splitlines()
    assert f"{FAULT}: 1 run(s), 1 unknown" in lines and "unknown-provenance runs: 1 of 1" in lines
    assert any(ln.startswith("none of the 1 run(s) is known to be held out") for ln in lines)
    assert "held-out eps_td" not in text and "held-out runs" not in text


def test_the_reports_validation_names_in_sample_and_held_out_runs(model: Path, recorded: dict) -> None:
    from replay.offline import NodeAlarms
    from replay.report.document import Figure, Paragraph, Table
    from replay.report.panels import RunSet, validation_panel

    bundle = load_bundle(model)
    (runs, sha), (fault, fault_sha) = recorded["runs"], recorded["fault"]
    labels = [f"engine1_runs #{i + 1}" for i in range(4)] + ["engine1_fault #1"]

    def words(run_set: RunSet) -> tuple[str, list[str]]:
        blocks = validation_panel(bundle, run_set, bundle.schedule, "yB", NodeAlarms([], 0))
        text = " ".join(b.text for b in blocks if isinstance(b, Paragraph))
        text += " ".join(b.caption for b in blocks if isinstance(b, Table | Figure))
        return text, [h for b in blocks if isinstance(b, Table) for h in b.header]

    text, header = words(RunSet([*runs, *fault], labels, [sha] * 4 + [fault_sha]))
    assert ("In-sample runs (among the model's training runs" in text
            and "engine1_runs #1, engine1_runs #2, engine1_runs #3, engine1_runs #4." in text)
    assert "Held-out runs (not among the model's training runs): engine1_fault #1." in text
    assert "yB, in-sample runs" in text and "yB, held-out runs" in text
    assert {"held-out eps_td", "in-sample eps_td", "in-sample R\u00b2"} <= set(header)

    text, header = words(RunSet(runs, labels[:4]))  # the training runs alone, by their spans
    assert "None of these runs is held out." in text and "in-sample eps_td" in header
    assert not any("held-out" in h for h in header) and "Held-out runs" not in text
    assert "eps_td" not in header  # no eps_td column without its runs' name
