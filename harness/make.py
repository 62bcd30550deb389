"""Recordings and models for the benchmarks, made by the product's own entries (never the command
line): ``simulate`` (``simulator.files``), ``train`` (``node.training.fit``) and ``replay``
(``replay.offline``)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from node.contract.errors import OrdervibError
from node.contract.schedule import load_schedule
from node.training.fit import Trained, model_options, save_trained, train_recordings
from replay.offline import ReplayReport, replay_model_file
from simulator.files import Simulation, simulate_files


def simulate(out: str | os.PathLike, **settings: Any) -> dict:
    """Simulate ``Simulation(**settings)`` into ``out`` (+ its schedule and truth); its truth."""
    out = os.fspath(out)
    simulate_files(Simulation(**settings), out)
    return json.loads(Path(out).with_suffix(".truth.json").read_text())


def sample_model(out: str | os.PathLike) -> str:
    """The benchmarks' default model: a Lasso bundle of yB trained on the committed sample runs
    (``recordings/engine1_runs.mcap``), written to ``out``; its path."""
    recs = Path(__file__).resolve().parent.parent / "recordings"
    train([recs / "engine1_runs.mcap"], recs / "engine1_runs.schedule.toml", out, method="lasso", target="yB")
    return os.fspath(out)


def train(recordings: list[str | os.PathLike], schedule: str | os.PathLike, out: str | os.PathLike,
          workers: int | None = None, keep_runs: bool = True, **options: Any) -> Trained:
    """Train with the model options ``options`` (``node.training.fit.model_options``) on the
    recordings, quietly, and write the model folder ``out`` (an earlier model there is replaced)."""
    trained = train_recordings([os.fspath(r) for r in recordings], load_schedule(os.fspath(schedule)),
                               model_options(**options), workers=workers, quiet=True)
    folder = Path(out)
    if (folder / "manifest.json").exists():  # an earlier model of the bench's: replaced whole
        shutil.rmtree(folder)
    elif folder.exists() and any(folder.iterdir()):
        raise OrdervibError(f"{folder} is a folder of other things, not a model")
    save_trained(trained, folder, keep_runs)
    return trained


def replay(recording: str | os.PathLike, model: str | os.PathLike, out: str | None = None,
           workers: int | None = None) -> ReplayReport:
    """The node offline over ``recording`` with the model folder ``model``."""
    return replay_model_file(os.fspath(recording), os.fspath(model), out, workers)
