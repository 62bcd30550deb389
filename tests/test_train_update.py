"""``ordervib train --update``: runs added to a model equal a full retrain on all of them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from node.cli import main

SIM = ["--channels", "nB,yA,yB,tF", "--plateau-scale", "0.05", "--quiet"]


@pytest.fixture(scope="module")
def four_and_four(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """a.mcap: runs 1-4 of one engine, b.mcap: runs 5-8; ``full`` trained on both, ``m4`` on a."""
    d = tmp_path_factory.mktemp("update")
    assert main(["simulate", "--runs", "4", "--seed", "5", "--out", str(d / "a.mcap"), *SIM]) == 0
    assert main(["simulate", "--runs", "8", "--skip", "4", "--seed", "5", "--out", str(d / "b.mcap"),
                 *SIM]) == 0
    sched = str(d / "a.schedule.toml")
    assert main(["train", str(d / "a.mcap"), str(d / "b.mcap"), "--schedule", sched, "--out", str(d / "full"),
                 "--workers", "1", "--quiet"]) == 0
    assert main(["train", str(d / "a.mcap"), "--schedule", sched, "--out", str(d / "m4"), "--quiet",
                 "--workers", "1"]) == 0
    return d


def _manifests(model: Path) -> list[dict]:
    """Every manifest of a model folder (the top one and each target's), training time left out."""
    out = []
    for f in sorted(model.rglob("manifest.json")):
        m = json.loads(f.read_text())
        m.get("training", {}).pop("seconds", None)
        out.append(m)
    return out


def _arrays(f: Path) -> dict[str, np.ndarray]:
    with np.load(f, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def _same_arrays(a: Path, b: Path) -> None:
    x, y = _arrays(a), _arrays(b)
    assert sorted(x) == sorted(y)
    for k in x:
        np.testing.assert_array_equal(x[k], y[k], err_msg=k)


def test_four_runs_updated_with_four_equal_training_on_eight(four_and_four: Path) -> None:
    d = four_and_four
    assert main(["train", "--update", str(d / "m4"), str(d / "b.mcap"), "--out", str(d / "upd"),
                 "--workers", "1", "--quiet"]) == 0
    full, upd = d / "full", d / "upd"
    manifests = _manifests(full)
    assert len(manifests) == 3  # the model and its two targets, yA and yB
    assert manifests == _manifests(upd)  # CV choices, CV errors, thresholds, provenance
    for f in sorted(full.rglob("*.npz")):
        _same_arrays(f, upd / f.relative_to(full))
    assert json.loads((upd / "training-runs.json").read_text())["recordings"] == \
        [{"path": str(d / n), "sha256": r["sha256"]} for n, r in
         zip(["a.mcap", "b.mcap"], manifests[1]["training"]["recordings"])]
    # the four-run model differs: the update did change it
    assert _manifests(d / "m4") != manifests


def test_update_refuses_what_would_change_or_lose_the_model(
        four_and_four: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = four_and_four
    before = (d / "full" / "manifest.json").read_bytes()
    cases = [
        (["--out", str(d / "full"), "--update", str(d / "full")], "holds an input of this command"),
        (["--out", str(d / "x"), "--update", str(d / "m4"), "--method", "lasso"], "--method cannot be given"),
        (["--out", str(d / "x"), "--update", str(d / "m4"), "--schedule", str(d / "a.schedule.toml")],
         "--schedule cannot be given"),
        (["--out", str(d / "x"), "--update", str(d / "a.mcap")], "model bundle not found"),
    ]
    for extra, message in cases:
        assert main(["train", str(d / "b.mcap"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert (d / "full" / "manifest.json").read_bytes() == before
    assert not (d / "x").exists()


def test_a_model_without_kept_runs_or_with_damaged_ones_is_one_line(
        four_and_four: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = four_and_four
    assert main(["train", str(d / "a.mcap"), "--schedule", str(d / "a.schedule.toml"), "--out",
                 str(tmp_path / "bare"), "--no-keep-runs", "--method", "lasso", "--inputs", "nB",
                 "--no-prom", "--quiet"]) == 0
    assert not (tmp_path / "bare" / "training-runs.npz").exists()
    capsys.readouterr()
    assert main(["train", "--update", str(tmp_path / "bare"), str(d / "b.mcap"), "--out",
                 str(tmp_path / "x")]) == 2
    assert "keeps no training runs" in capsys.readouterr().err
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    for f in (d / "m4").rglob("*"):
        if f.is_file():
            (damaged / f.relative_to(d / "m4")).parent.mkdir(parents=True, exist_ok=True)
            (damaged / f.relative_to(d / "m4")).write_bytes(f.read_bytes())
    runs = damaged / "training-runs.npz"
    runs.write_bytes(runs.read_bytes()[: runs.stat().st_size // 2])
    assert main(["train", "--update", str(damaged), str(d / "b.mcap"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert "damaged training runs" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "x").exists()
