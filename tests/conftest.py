"""Shared test fixtures' building blocks."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sklearn.utils.estimator_checks import check_estimator

from node.cli import main
from node.runtime import align

SMALL_CHANNELS = ["--channels", "nB,yB,tF", "--plateau-scale", "0.05", "--quiet"]


def small_campaign(d: Path, seed: int) -> Path:
    """In ``d``: train.mcap (2 short runs), test.mcap (the next one), model ``m`` (Lasso on nB, tF).

    Three channels and plateaus at 5 % keep it to a few seconds; returns ``d``.
    """
    assert main(["simulate", "--runs", "2", "--seed", str(seed), "--out", str(d / "train.mcap"),
                 *SMALL_CHANNELS]) == 0
    assert main(["simulate", "--runs", "3", "--skip", "2", "--seed", str(seed),
                 "--out", str(d / "test.mcap"), *SMALL_CHANNELS]) == 0
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"),
                 "--out", str(d / "m"), "--method", "lasso", "--inputs", "nB,tF", "--quiet",
                 "--workers", "1"]) == 0
    return d


@pytest.fixture(scope="module")
def numpy_path_from_16_messages() -> Iterator[None]:
    """For modules of small batches: those of 16 messages and more take ``push_columns``' numpy
    path (the node's threshold is higher, where that path pays), so that it is checked too."""
    old, align.SMALL_BATCH = align.SMALL_BATCH, 16
    yield
    align.SMALL_BATCH = old


@pytest.fixture(scope="session")
def phased(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """train.mcap (3 short runs with phase), a model trained on them (lasso on nB, curves on);
    shared by the phase and the average tests (read only)."""
    d = tmp_path_factory.mktemp("phase")
    assert main(["simulate", "--runs", "3", "--seed", "5", "--plateau-scale", "0.3", "--out",
                 str(d / "train.mcap"), "--quiet"]) == 0
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(d / "model"), "--method", "lasso", "--inputs", "nB", "--target", "yB", "--quiet",
                 "--workers", "1"]) == 0
    return d


def node_messages(bundle, runs) -> list[dict]:
    """The monitor messages of one ``MonitorPipeline`` stepped over ``runs`` (training ``Run``s,
    each its own run), in order."""
    from node.runtime.align import AlignedSample
    from node.runtime.pipeline import MonitorPipeline

    pipe = MonitorPipeline(bundle)
    out = []
    for run in runs:
        for k in range(len(run.t)):
            vals = {c: float(run.data[k, j]) for j, c in enumerate(run.channels)}
            out.append(pipe.step(AlignedSample(float(run.t[k]), vals, k == 0))[0])
    return out


def check_estimator_statuses(estimator: object, expected_failed: dict[str, str],
                             may_skip: set[str]) -> dict[str, set[str]]:
    """scikit-learn's ``check_estimator`` on ``estimator``: asserts that no check fails but the
    named ``expected_failed`` ones, that each of those really fails (no stale entry) and that
    none is skipped but ``may_skip``; returns the check names by status."""
    results = check_estimator(estimator, expected_failed_checks=expected_failed, on_fail=None,
                              on_skip=None)
    failed = [f"{r['check_name']}: {r['exception']!r}" for r in results if r["status"] == "failed"]
    assert not failed, "\n".join(failed)
    by_status: dict[str, set[str]] = {}
    for r in results:
        by_status.setdefault(r["status"], set()).add(r["check_name"])
    assert by_status.get("xfail", set()) == set(expected_failed)
    assert by_status.get("skipped", set()) <= may_skip
    return by_status
