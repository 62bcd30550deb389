"""Whether a model was trained on given recording files: one rule (``node.training.provenance``)
for ``ordervib demo`` (reuse its model) and ``ordervib predict`` (read the training recordings
again)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from node.contract.schedule import OperatingCondition, Schedule
from node.models.bundle import Bundle, Model, sha256_file
from node.training.provenance import trained_on, training_recordings

SCHEDULE = Schedule((OperatingCondition("A", 4000.0),))


def _model(*recordings: dict, targets: tuple[str, ...] = ("yB",)) -> Model:
    training = {"recordings": list(recordings), "runs": 1}
    return Model(tuple(Bundle("lasso", tg, SCHEDULE, [], training=training) for tg in targets))


def _file(tmp_path: Path, name: str, text: str) -> tuple[Path, dict]:
    path = tmp_path / name
    path.write_text(text)
    return path, {"path": str(path), "sha256": sha256_file(path)}


def test_trained_on_exactly_the_recordings_in_order(tmp_path: Path) -> None:
    a, rec_a = _file(tmp_path, "a.mcap", "a")
    b, rec_b = _file(tmp_path, "b.mcap", "b")
    model = _model(rec_a, rec_b, targets=("yA", "yB", "yC"))
    assert trained_on(model, [a, b])
    assert trained_on(model.bundles[0], [str(a), str(b)])
    assert not trained_on(model, [a]) and not trained_on(model, [b, a]) and not trained_on(model, [a, b, a])
    a.write_text("changed")
    assert not trained_on(model, [a, b])
    assert not trained_on(_model(), [b]) and not trained_on(_model({"path": str(b)}), [b])


def test_training_recordings_only_when_each_is_still_the_file_trained_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    a, rec_a = _file(tmp_path, "a.mcap", "a")
    b, rec_b = _file(tmp_path, "b.mcap", "b")
    assert training_recordings(_model(rec_a, rec_b)) == [str(a), str(b)]
    assert training_recordings(_model()) == []
    with caplog.at_level(logging.INFO, "node.training.provenance"):
        b.write_text("changed")
        assert training_recordings(_model(rec_a, rec_b)) == []
        assert training_recordings(_model(rec_a, {"sha256": rec_b["sha256"]})) == []
    assert [r.getMessage() for r in caplog.records] == [
        f"the model's training recording {b} is not there as it was: not used",
        "the model's training recording None is not there as it was: not used"]
