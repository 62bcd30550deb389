"""Import speed: ``ordervib import`` of one full-length simulated run against writing the same run.

    .venv/bin/python -m bench import-speed [--seed S]

Simulates one pass-off run (every channel and the phases), writes it as an MDF4 file
(asammdf, 100 Hz, speeds in rad/s) and as a CSV export (80 Hz, temperatures in K), imports
each (``node.ingest.import_file``, the work of ``ordervib import``) and prints the messages per
second beside the simulator's own writer (``simulator.export.write_recording``) on the same
run: the floor an import cannot beat, since it writes as many messages and reads a file too.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from node.contract import PHASE_CHANNELS, SENSOR_CHANNELS
from node.ingest import import_file, load_map
from node.ingest.sources import source_format
from simulator.campaign import simulate_campaign
from simulator.export import write_recording

CHANNELS = SENSOR_CHANNELS + PHASE_CHANNELS


def _source(t_run: np.ndarray, values: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The run's samples linearly interpolated every ``step`` s (a dropout's neighbourhood NaN)."""
    t = np.arange(t_run[0], t_run[-1], step)
    cols = []
    for j in range(values.shape[1]):
        v = values[:, j]
        nan = np.isnan(v)
        x = np.interp(t, t_run, np.where(nan, 0.0, v))
        x[np.interp(t, t_run, nan.astype(float)) > 0] = np.nan
        cols.append(x)
    return t, np.column_stack(cols)


def _map(path: Path, fmt: str, time_table: str) -> None:
    lines = ['bed = "bench"', time_table]
    for ch in CHANNELS:
        lines.append(f'[channels.{ch}]\nsource = "src_{ch}"')
        if ch == "nA":
            lines.append('unit = "rad/s"')
        elif ch[0] == "t" and fmt == "csv":
            lines.append('unit = "K"')
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="python -m bench import-speed")
    p.add_argument("--seed", type=int, default=11)
    args = p.parse_args(argv)
    from asammdf import MDF, Signal

    campaign = simulate_campaign(1, args.seed)
    run = campaign.runs[0]
    assert run.phase is not None
    values = np.column_stack([run.data, run.phase])
    print(f"one simulated run: {len(run.t)} samples at 40 Hz ({run.t[-1] - run.t[0]:.0f} s), "
          f"{len(CHANNELS)} channels")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        start = time.perf_counter()
        n_sim = write_recording(campaign, d / "sim.mcap", "bench", args.seed)
        rates = {"simulator's writer (same run)": (n_sim, time.perf_counter() - start)}
        t0 = math.floor(run.t[0])
        t, x = _source(run.t, values, 0.01)
        x[:, 0] *= 2 * math.pi / 60.0  # nA in rad/s
        mdf = MDF(version="4.10")
        mdf.header.start_time = dt.datetime.fromtimestamp(t0, tz=dt.UTC)
        mdf.append([Signal(x[:, j], t - t0, name=f"src_{ch}") for j, ch in enumerate(CHANNELS)])
        mdf.save(d / "cell.mf4", overwrite=True)
        mdf.close()
        _map(d / "mf4.toml", "mf4", "")
        t, x = _source(run.t, values, 0.0125)
        x[:, 0] *= 2 * math.pi / 60.0
        temps = [j for j, ch in enumerate(CHANNELS) if ch[0] == "t"]
        x[:, temps] += 273.15
        with open(d / "cell.csv", "w") as f:
            f.write("time," + ",".join(f"src_{ch}" for ch in CHANNELS) + "\n")
            for i in range(len(t)):
                f.write(repr(float(t[i])) + "," + ",".join("" if v != v else repr(v) for v in x[i].tolist())
                        + "\n")
        _map(d / "csv.toml", "csv", '[time]\ncolumn = "time"')
        for fmt in ("mf4", "csv"):
            src = str(d / f"cell.{fmt}")
            size = os.path.getsize(src) / 1e6
            start = time.perf_counter()
            imap = load_map(d / f"{fmt}.toml")
            report = import_file(src, imap, source_format(src, None), d / f"{fmt}.mcap")
            rates[f"import {fmt} ({size:.1f} MB)"] = (report.messages, time.perf_counter() - start)
    base = rates["simulator's writer (same run)"]
    for name, (n, secs) in rates.items():
        print(f"{name:32s} {n:9d} messages in {secs:6.2f} s = {n / secs:9.0f} msg/s"
              f"  ({secs / base[1]:.2f}x the writer's time)")
    return 0
