"""The training runs a model bundle keeps, so that ``ordervib train --update`` adds new runs
without reading the old recordings again, and gives the model a full retrain would.

What is kept is the training data itself: every run on the node's 40 Hz grid as ``read_runs``
gave it (``Run``: times, every channel, bed, shutdown before), compressed, in
``training-runs.npz`` (arrays ``t<i>`` (K,) s and ``data<i>`` (K, c), float64), with
``training-runs.json`` beside it (format, version, each run's channels, bed and shutdown,
the recordings read, and the training options). The demo's eight training runs: 36.5 MB of
recording, about 5 MB kept.

Why the runs and not per-run normal-equation terms: hardly any of training is a sum over
runs. The engine history's cooling rate is estimated from all runs together and changes every
run's history channels; the fleet curve, and so every run's ``run_curve`` input, is binned over
all runs; MS-DPCCA ranks the inputs over the fold's runs; the output-error refits and the
alarm thresholds depend on the held-out predictions of every fold. A model equal to a full
retrain, CV choices and calibration included, needs the runs (the reading is what the update
saves: the 40-run set reads in about 30 s).
"""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path

import numpy as np

from node.contract.documents import parse_document, read_document, read_npz
from node.contract.errors import OrdervibError
from node.training.runs import Run

RUNS_ARRAYS = "training-runs.npz"
RUNS_META = "training-runs.json"
FORMAT = "ordervib-training-runs"
FORMAT_VERSION = 1
# Bounds of the kept runs, read as untrusted input (node.contract.documents.read_npz): the
# demo's eight runs are 20 MB (the largest array 2.6 MB); a run of 12 h at 40 Hz over 64
# channels is 1.1e8 values.
MAX_RUN_ELEMENTS = 1 << 27  # values in one array (1 GiB of float64)
MAX_RUNS_BYTES = 16 << 30  # the arrays' bytes, all runs together (uncompressed)


def save_kept_runs(runs: list[Run], folder: str | os.PathLike, options: dict,
                   recordings: list[dict]) -> None:
    """Write ``runs`` (in training order), the training ``options`` (JSON values) and the
    ``recordings`` read (path, sha256) into the model folder ``folder``."""
    out = Path(folder)
    arrays: dict[str, np.ndarray] = {}
    for i, r in enumerate(runs):
        arrays[f"t{i}"] = np.asarray(r.t, dtype=float)
        arrays[f"data{i}"] = np.asarray(r.data, dtype=float)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]  # numpy's stub: ** as allow_pickle
    (out / RUNS_ARRAYS).write_bytes(buf.getvalue())
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "options": options,
            "recordings": recordings,
            "runs": [{"channels": list(r.channels), "bed": r.bed, "shutdown_before": r.shutdown_before}
                     for r in runs]}
    (out / RUNS_META).write_text(json.dumps(meta, indent=1))


def load_kept_runs(folder: str | os.PathLike) -> tuple[list[Run], dict, list[dict]]:
    """The runs, the training options and the recordings a model folder keeps; an
    ``OrdervibError`` (one line) when it keeps none or they are damaged."""
    root = Path(folder)
    if not (root / RUNS_META).is_file() or not (root / RUNS_ARRAYS).is_file():
        raise OrdervibError(f"{folder} keeps no training runs (trained by an older ordervib or with "
                            f"--no-keep-runs): train again on all the recordings")
    text = read_document(root / RUNS_META, str(root / RUNS_META))
    meta = parse_document(text, FORMAT, FORMAT_VERSION, str(root / RUNS_META), "training-runs",
                          version_key="format_version")
    try:
        infos = list(meta["runs"])
        widths = [len(info["channels"]) for info in infos]
        names = {f"{k}{i}" for i in range(len(infos)) for k in ("t", "data")}

        def shape_check(name: str, shape: tuple[int, ...]) -> None:
            i = int(name.removeprefix("data").removeprefix("t"))
            if not (shape[1:] == (widths[i],) if name.startswith("data") else len(shape) == 1):
                raise ValueError(f"shape {shape} does not fit run {i}'s {widths[i]} channels")

        arrays = read_npz(root / RUNS_ARRAYS, f"{root / RUNS_ARRAYS}: damaged training runs",
                          names.__contains__, MAX_RUN_ELEMENTS, MAX_RUNS_BYTES, shape_check)
        runs = [_run(arrays, i, info) for i, info in enumerate(infos)]
        options, recordings = dict(meta["options"]), list(meta["recordings"])
    except (ValueError, KeyError, TypeError) as exc:
        raise OrdervibError(f"{root / RUNS_ARRAYS}: damaged training runs ({exc})") from None
    if not runs:
        raise OrdervibError(f"{root / RUNS_META} lists no run")
    return runs, options, recordings


def _run(arrays: dict[str, np.ndarray], i: int, info: dict) -> Run:
    t, data = arrays[f"t{i}"], arrays[f"data{i}"]
    channels = tuple(str(c) for c in info["channels"])
    if t.dtype != float or data.dtype != float or t.ndim != 1 or data.shape != (len(t), len(channels)):
        raise ValueError(f"run {i}: arrays t {t.shape} and data {data.shape} do not fit "
                         f"{len(channels)} channels")
    shutdown = info["shutdown_before"]
    if shutdown is not None and not (isinstance(shutdown, (int, float)) and math.isfinite(shutdown)):
        raise ValueError(f"run {i}: shutdown_before {shutdown!r}")
    return Run(t, data, channels, str(info["bed"]), None if shutdown is None else float(shutdown))
