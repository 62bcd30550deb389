"""Writing a simulated campaign: MCAP recording, schedule TOML, ground-truth JSON.

The MCAP layout is ``node.mcap``'s; this module only adds what a test bed
adds: acquisition jitter on t (< 2 ms, 0.1 ms resolution), a receive latency
(publish_time) and the arrival order (messages written in publish-time order).
The order phases, when written, take their jitter and latency from a stream of
their own, so every other message is the very same with or without them.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable

import numpy as np
import orjson

from node.contract import FS, PHASE_CHANNELS, is_phase_channel, log_times_ns, sensor_key
from node.mcap import RecordingWriter
from simulator.campaign import (
    NOISE,
    PHASE_DECIMALS,
    PHASE_MIN_AMPLITUDE,
    PHASE_SIGMA_CAP,
    Campaign,
)
from simulator.rotor import TAU_TRACKER

JITTER_SIGMA = 0.4e-3  # acquisition jitter, s
JITTER_MAX = 1.5e-3  # never more (a slot is 25 ms wide)
LATENCY_BASE = 0.8e-3  # receive latency: base + per-channel scan offset + exponential tail, s
LATENCY_SCAN = 0.05e-3
LATENCY_TAIL = 0.3e-3
LATENCY_RESOLUTION_NS = 100_000  # receive clock resolution, 0.1 ms
Messages = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # channel, t, value, publish


PHASE_TRUTH = {
    "unit": "degrees",
    "convention": (
        "lag from the once-per-rev mark of the order smoothed by the tracker (a first-order "
        "lag of tracker_s on the complex order), wrapped into [-180, 180)"
    ),
    "tracker_s": TAU_TRACKER,
    "min_amplitude_mm_s": PHASE_MIN_AMPLITUDE,
    "sigma_deg": (
        f"noise_scale x degrees(({NOISE['y'][0]:g} + {NOISE['y'][1]:g} A) / A), A the clean "
        f"amplitude in mm/s (at least min_amplitude_mm_s), at most sigma_cap_deg"
    ),
    "sigma_cap_deg": PHASE_SIGMA_CAP,
    "resolution_deg": 10.0**-PHASE_DECIMALS,
}


def run_messages(
    grid: np.ndarray, data: np.ndarray, rng: np.random.Generator, first: int = 0
) -> Messages:
    """One run's messages in arrival order: (channel index, t s, value, publish_time ns).

    grid: (K,) s, the run's 40 Hz grid; data: (K, C) values, NaN for a dropout; first:
    the index of data's first column among the written channels (its latency's scan
    offset). All outputs (K * C,); channel index from ``first``.
    """
    k, c = data.shape
    jitter = np.clip(rng.normal(0.0, JITTER_SIGMA, (k, c)), -JITTER_MAX, JITTER_MAX)
    t = np.round(grid[:, None] + jitter, 4)
    scan = first + np.arange(c)
    latency = LATENCY_BASE + LATENCY_SCAN * scan + rng.exponential(LATENCY_TAIL, (k, c))
    res = LATENCY_RESOLUTION_NS
    publish = log_times_ns(t) + np.rint(latency * 1e9 / res).astype(np.int64) * res
    order = np.argsort(publish, axis=None, kind="stable")
    col = np.broadcast_to(scan, (k, c)).ravel()[order]
    return col, t.ravel()[order], data.ravel()[order], publish.ravel()[order]


def _merged(a: Messages, b: Messages) -> Messages:
    """Two message sets (as ``run_messages`` returns) as one, in publish-time order.

    A stable sort: ``a``'s messages keep their order among themselves, and go first on a tie.
    """
    order = np.argsort(np.concatenate([a[3], b[3]]), kind="stable")
    col, t, value, publish = (np.concatenate([x, y])[order] for x, y in zip(a, b, strict=True))
    return col, t, value, publish


def write_recording(
    campaign: Campaign,
    path: str | os.PathLike,
    bed: str,
    seed: int,
    first_run: int = 0,
    progress: Callable[[float], None] | None = None,
    message_index: bool = True,
    channels: tuple[str, ...] | None = None,
) -> int:
    """Write the runs from ``first_run`` on to an MCAP file; returns the message count.

    channels: the channels to write (default ``campaign.published``: all, with the order
    phases if simulated); the phases are registered and numbered after the others.
    With message indexes by default, as contract section 3 asks (indexed readers such as
    Foxglove's ``McapIndexedReader`` refuse a chunk index without them); they cost 16 bytes
    per message; ``message_index=False`` leaves them out.
    """
    channels = campaign.published if channels is None else channels
    missing = [ch for ch in channels if ch not in campaign.published]
    if missing:
        raise ValueError(f"the campaign has no channel {', '.join(missing)}")
    plain = [ch for ch in channels if not is_phase_channel(ch)]
    phases = [ch for ch in channels if is_phase_channel(ch)]
    cols = [campaign.channels.index(ch) for ch in plain]
    phase_cols = [PHASE_CHANNELS.index(ch) for ch in phases]
    keys = [sensor_key(bed, ch) for ch in (*plain, *phases)]
    runs = campaign.runs[first_run:]
    total = sum(len(r.t) for r in runs) * len(keys)
    done = 0
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E57BED]))
    phase_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E57BED, 1]))
    with RecordingWriter(path, message_index=message_index) as writer:
        for key in keys:  # register every channel up front, in table order
            writer.channel_id(key)
        for run in runs:
            msgs = run_messages(run.t, run.data[:, cols], rng)
            if phase_cols:
                assert run.phase is not None
                msgs = _merged(msgs, run_messages(run.t, run.phase[:, phase_cols], phase_rng,
                                                  first=len(cols)))
            col, t, value, publish = msgs
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
    """The ground truth of the written runs, as a JSON-ready dict.

    ``phase``: how the order phases were measured, null when none is written; ``rotor``: the
    engine's modes and the order tracker's lag; each run's ``criticals``: the critical speeds
    crossed.
    """
    channels = campaign.published if channels is None else channels
    return {
        "generator": "ordervib simulate",
        "seed": seed,
        "bed": bed,
        "channels": list(channels),
        "phase": ({**PHASE_TRUTH, "tracker_s": campaign.tracker_s}
                  if any(is_phase_channel(ch) for ch in channels) else None),
        "sample_rate_hz": FS,
        "noise_scale": campaign.noise_scale,
        "schedule": campaign.schedule.truth(),
        "rotor": {
            "model": "modal unbalance response (simulator/rotor.py)",
            "tracker_s": campaign.tracker_s,
            "modes": campaign.modes,
            "notes": (
                "per amplitude channel its modes: rpm_cold is the critical speed (shaft rpm) at "
                "15 C metal; it falls as sqrt(1 - kappa_per_K (metal - 15)) and with a stiffness "
                "fault as sqrt(factor); af = 1 / (2 zeta). Each run's criticals list every "
                "crossing of a critical: t (epoch s), speed (the critical then, rpm), rate_rpm_s."
            ),
        },
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
