"""Writing a simulated campaign: MCAP recording, schedule TOML, ground-truth JSON.

The MCAP layout is ``node.mcap``'s; this module only adds what a test bed
adds: acquisition jitter on t (< 2 ms, 0.1 ms resolution), a receive latency
(publish_time) and the arrival order (messages written in publish-time order).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable

import numpy as np
import orjson

from node.contract import FS, sensor_key
from node.mcap import RecordingWriter
from simulator.campaign import Campaign, SimRun

JITTER_SIGMA = 0.4e-3  # acquisition jitter, s
JITTER_MAX = 1.5e-3  # never more (a slot is 25 ms wide)
LATENCY_BASE = 0.8e-3  # receive latency: base + per-channel scan offset + exponential tail, s
LATENCY_SCAN = 0.05e-3
LATENCY_TAIL = 0.3e-3
LATENCY_RESOLUTION_NS = 100_000  # receive clock resolution, 0.1 ms


def run_messages(
    run: SimRun, rng: np.random.Generator, channels: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The run's messages in arrival order: (channel index, t s, value, publish_time ns).

    All (K * C,); value NaN for a dropout.
    """
    k, c = run.data.shape
    jitter = np.clip(rng.normal(0.0, JITTER_SIGMA, (k, c)), -JITTER_MAX, JITTER_MAX)
    t = np.round(run.t[:, None] + jitter, 4)
    latency = LATENCY_BASE + LATENCY_SCAN * np.arange(c) + rng.exponential(LATENCY_TAIL, (k, c))
    res = LATENCY_RESOLUTION_NS
    publish = np.rint(t * 1e9).astype(np.int64) + np.rint(latency * 1e9 / res).astype(np.int64) * res
    order = np.argsort(publish, axis=None, kind="stable")
    col = np.broadcast_to(np.arange(c), (k, c)).ravel()[order]
    return col, t.ravel()[order], run.data.ravel()[order], publish.ravel()[order]


def write_recording(
    campaign: Campaign,
    path: str | os.PathLike,
    bed: str,
    seed: int,
    first_run: int = 0,
    progress: Callable[[float], None] | None = None,
    message_index: bool = False,
    channels: tuple[str, ...] | None = None,
) -> int:
    """Write the runs from ``first_run`` on to an MCAP file; returns the message count.

    Without message indexes by default: they would double the file (16 bytes per
    message); readers seek by the chunk index and sort inside a chunk.
    """
    channels = campaign.channels if channels is None else channels
    cols = [campaign.channels.index(ch) for ch in channels]
    keys = [sensor_key(bed, ch) for ch in channels]
    runs = [SimRun(r.t, r.data[:, cols], r.truth) for r in campaign.runs[first_run:]]
    total = sum(r.data.size for r in runs)
    done = 0
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E57BED]))
    with RecordingWriter(path, message_index=message_index) as writer:
        for key in keys:  # register every channel up front, in table order
            writer.channel_id(key)
        for run in runs:
            col, t, value, publish = run_messages(run, rng, channels)
            ts = t.tolist()
            vs = [None if x != x else x for x in value.tolist()]
            ps = publish.tolist()
            dumps, write = orjson.dumps, writer.write
            step = max(len(ts) // 20, 1)
            for i, j in enumerate(col.tolist()):
                write(keys[j], ts[i], dumps({"t": ts[i], "v": vs[i]}), ps[i])
                if progress is not None and i % step == 0:
                    progress((done + i) / total)
            done += len(ts)
    if progress is not None:
        progress(1.0)
    return done


def truth_document(
    campaign: Campaign,
    bed: str,
    seed: int,
    first_run: int = 0,
    channels: tuple[str, ...] | None = None,
) -> dict:
    """The ground truth of the written runs, as a JSON-ready dict."""
    return {
        "generator": "ordervib simulate",
        "seed": seed,
        "bed": bed,
        "channels": list(campaign.channels if channels is None else channels),
        "sample_rate_hz": FS,
        "noise_scale": campaign.noise_scale,
        "schedule": campaign.schedule.truth(),
        "notes": (
            "times are seconds since the Unix epoch; shutdown_before_s is the time from the "
            "previous run's engine stop (every shaft speed below 5 % of its maximum) to this "
            "run's engine start; null for the first run (a cold engine, soaked at ambient)."
        ),
        "runs": [r.truth for r in campaign.runs[first_run:]],
    }


def write_sidecars(
    campaign: Campaign,
    mcap_path: str,
    bed: str,
    seed: int,
    first_run: int = 0,
    channels: tuple[str, ...] | None = None,
) -> tuple[str, str]:
    """Write REC.schedule.toml and REC.truth.json beside REC.mcap; returns their paths."""
    stem = mcap_path[:-5] if mcap_path.endswith(".mcap") else mcap_path
    schedule_path, truth_path = stem + ".schedule.toml", stem + ".truth.json"
    with open(schedule_path, "w", encoding="utf-8") as f:
        f.write(campaign.schedule.toml())
    with open(truth_path, "w", encoding="utf-8") as f:
        json.dump(truth_document(campaign, bed, seed, first_run, channels), f, indent=1)
        f.write("\n")
    return schedule_path, truth_path
