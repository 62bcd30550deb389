"""Whether a run was among a model's training runs: "in-sample", "held-out" or "unknown".

The one rule behind the words of ``ordervib evaluate`` and ``ordervib report``, and behind
whether a model was trained on given recording files (``trained_on``: ``ordervib demo`` reuses
its model, ``training_recordings``: ``ordervib predict`` reads them again). Training
records its runs in every bundle's ``training`` dict (``training_record``, kept in
manifest.json): the recordings read (``{"path", "sha256"}``), the number of runs, and each
run's span ``[bed, t_first, t_last]`` (s since the epoch: its first and last sample on the
40 Hz grid), the kept runs of an update included. ``run_provenance`` calls a run in-sample
when it matches a training run's span (the same bed, both ends within half a sample,
``SPAN_TOLERANCE``: a run is recognised in any file, e.g. a node's own recording of a
replay) or when its recording's sha256 is a training recording's (the whole file was trained
on); otherwise held-out. A model trained before the spans were recorded knows only its
recordings' hashes: a run of another file is then "unknown", neither in-sample nor held-out.

>>> import numpy as np
>>> from node.training.runs import Run
>>> def run(t0: float, bed: str = "bed1") -> Run:
...     return Run(t0 + np.arange(400) / 40, np.zeros((400, 1)), ("nB",), bed, None)
>>> trained = [run(100.0)]
>>> record = training_record([{"path": "train.mcap", "sha256": "aa"}], trained, 1.0)
>>> record["run_spans"]
[['bed1', 100.0, 109.975]]
>>> from node.contract.schedule import OperatingCondition, Schedule
>>> schedule = Schedule((OperatingCondition("A", 4000.0),))
>>> bundle = Bundle("lasso", "yB", schedule, [], training=record)
>>> run_provenance(bundle, [run(100.0), run(100.01), run(100.0, "bed2"), run(500.0)])
['in-sample', 'in-sample', 'held-out', 'held-out']
>>> run_provenance(bundle, [run(500.0)], ["aa"])  # from a training recording
['in-sample']
>>> old = Bundle("lasso", "yB", schedule, [], training={k: record[k] for k in ("recordings", "runs")})
>>> run_provenance(Model((old,)), [run(100.0), run(100.0)], ["aa", "bb"])  # no spans: by hash only
['in-sample', 'unknown']
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence

from node.contract import FS
from node.models.bundle import Bundle, Model, as_model, sha256_file
from node.training.runs import Run

log = logging.getLogger(__name__)

IN_SAMPLE = "in-sample"  # among the model's training runs
HELD_OUT = "held-out"  # not among them
UNKNOWN = "unknown"  # the model's record cannot tell
PROVENANCES = (HELD_OUT, IN_SAMPLE, UNKNOWN)  # the order runs are shown in
# How a table names the eps_td of runs of each provenance.
TABLE_WORDS = {HELD_OUT: "held-out", IN_SAMPLE: "in-sample", UNKNOWN: "unknown-provenance"}
SPAN_TOLERANCE = 0.5 / FS  # a run's ends within half a sample of a training run's: the same run, s


def run_spans(runs: Sequence[Run]) -> list[list]:
    """Each run's ``[bed, t_first, t_last]`` (s since the epoch), in order: JSON values."""
    return [[r.bed, float(r.t[0]), float(r.t[-1])] for r in runs]


def training_record(recordings: list[dict], runs: Sequence[Run], seconds: float) -> dict:
    """A bundle's ``training`` dict: the recordings read (``{"path", "sha256"}``), how many
    runs, their spans (``run_spans``: every training run, kept ones first) and the seconds
    training took."""
    return {"recordings": recordings, "runs": len(runs), "run_spans": run_spans(runs),
            "seconds": round(seconds, 1)}


def _spans(training: dict) -> list[tuple[str, float, float]] | None:
    """The training runs' spans of a record; None when it has none (an older model) or they are
    malformed (the record then tells nothing by spans)."""
    spans = training.get("run_spans")
    if not isinstance(spans, list):
        return None
    try:
        return [(str(bed), float(t0), float(t1)) for bed, t0, t1 in spans]
    except (TypeError, ValueError):
        return None


def _recordings(training: dict) -> list[dict]:
    """The training recordings a record names, ``{"path", "sha256"}`` as training wrote them
    (an entry of another type: an empty dict)."""
    recs = training.get("recordings")
    return [r if isinstance(r, dict) else {} for r in recs] if isinstance(recs, list) else []


def _hashes(training: dict) -> set[str]:
    """The sha256 of the training recordings a record names."""
    return {r["sha256"] for r in _recordings(training) if isinstance(r.get("sha256"), str)}


def _one(training: dict, run: Run, sha256: str | None) -> str:
    """One bundle's word for one run (see the module's rule)."""
    if sha256 is not None and sha256 in _hashes(training):
        return IN_SAMPLE
    spans = _spans(training)
    if spans is None:
        return UNKNOWN
    t0, t1 = float(run.t[0]), float(run.t[-1])
    same = any(bed == run.bed and abs(a - t0) <= SPAN_TOLERANCE and abs(b - t1) <= SPAN_TOLERANCE
               for bed, a, b in spans)
    return IN_SAMPLE if same else HELD_OUT


def run_provenance(model: Bundle | Model, runs: Sequence[Run],
                   sha256: Sequence[str | None] | None = None) -> list[str]:
    """Per run, ``IN_SAMPLE``, ``HELD_OUT`` or ``UNKNOWN`` for a bundle or a model (a run among
    the training runs of any of its bundles is in-sample).

    sha256: per run, the hash of the recording it was read from (None where not known; e.g.
    ``node.training.fit.read_sourced``).
    """
    if sha256 is not None and len(sha256) != len(runs):
        raise ValueError(f"{len(sha256)} hashes for {len(runs)} runs")
    records = [b.training for b in model.bundles] if isinstance(model, Model) else [model.training]
    out = []
    for i, run in enumerate(runs):
        words = {_one(rec, run, None if sha256 is None else sha256[i]) for rec in records}
        out.append(IN_SAMPLE if IN_SAMPLE in words else UNKNOWN if UNKNOWN in words else HELD_OUT)
    return out


def trained_on(model: Bundle | Model, recordings: Sequence[str | os.PathLike]) -> bool:
    """Whether every bundle of ``model`` was trained on exactly the files ``recordings``, in
    order, by their sha256 (``sha256_file``): its record names their hashes and no other."""
    hashes = [sha256_file(path) for path in recordings]
    return all([r.get("sha256") for r in _recordings(b.training)] == hashes for b in as_model(model).bundles)


def training_recordings(model: Bundle | Model) -> list[str]:
    """The paths of the model's training recordings, as training recorded them, when every one
    is still the file training read (its sha256 as recorded); else none (the first one not there
    as it was is logged)."""
    paths = []
    for rec in _recordings(as_model(model).bundles[0].training):
        path = rec.get("path")
        if not isinstance(path, str) or not os.path.isfile(path) or sha256_file(path) != rec.get("sha256"):
            log.info("the model's training recording %s is not there as it was: not used", path)
            return []
        paths.append(path)
    return paths
