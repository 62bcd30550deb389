"""Pass-off runs of a recording, the training dataset: ``read_runs`` and ``Run``.

``read_runs`` reads every sensor payload (``read_payloads``), decodes them with the
contract's payload rule (``node.contract.decode_samples``), puts them on the 40 Hz
grid by the node's own rule (``node.contract.slotting``: the absolute grid, each
channel by its clock phase, its samples taken in the order they were recorded, so
every sample lands in the slot the node gave it) and splits them into runs:
time-major arrays (samples, channels).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.contract import (
    FS,
    SENSOR_CHANNELS,
    SPEED_CHANNELS,
    decode_samples,
    engine_off,
    parse_sensor_key,
    run_starts,
)
from node.contract.slotting import ChannelPhase
from node.mcap.reader import ReadStats, Source, read_payloads

MIN_RUN = 10.0  # shorter stretches of "engine on" are not runs (noise), s


@dataclass
class Run:
    """One pass-off run on the 40 Hz grid.

    t: (K,) seconds since the epoch; data: (K, len(channels)) float64, NaN where
    a sample is missing or a dropout; shutdown_before: seconds the engine was off
    before this run (None for the first run in the file).
    """

    t: np.ndarray
    data: np.ndarray
    channels: tuple[str, ...]
    bed: str
    shutdown_before: float | None

    def column(self, name: str) -> np.ndarray:
        """One channel's samples, shape (K,)."""
        return self.data[:, self.channels.index(name)]


def _order_channels(found: Sequence[str], wanted: Sequence[str] | None) -> tuple[str, ...]:
    if wanted is not None:
        return tuple(wanted)
    known = [c for c in SENSOR_CHANNELS if c in found]
    return tuple(known + sorted(c for c in found if c not in SENSOR_CHANNELS))


def _align(
    t: np.ndarray, col: np.ndarray, v: np.ndarray, n_channels: int
) -> tuple[int, np.ndarray]:
    """The samples of one run (t, col, v: (n,), each channel's in recorded order) on the
    node's grid: returns (k0, data (K, n_channels)), row i being slot k0 + i (time (k0 + i) / FS).
    A slot keeps a channel's first sample, as the node does (later ones are duplicates)."""
    k = np.empty(len(t), dtype=np.int64)
    for j in np.unique(col).tolist():
        mine = np.flatnonzero(col == j)
        k[mine] = ChannelPhase().slots(t[mine])
    k0 = int(k.min())
    data = np.full((int(k.max()) - k0 + 1, n_channels), np.nan)
    first = np.unique((k - k0) * n_channels + col, return_index=True)[1]
    data[k[first] - k0, col[first]] = v[first]
    return k0, data


def _ffill(x: np.ndarray) -> np.ndarray:
    """Fill NaN rows of each column with the last value before them (then the first after)."""
    out = x.copy()
    for j in range(x.shape[1]):
        col = out[:, j]
        ok = ~np.isnan(col)
        if not ok.any():
            continue
        idx = np.where(ok, np.arange(len(col)), 0)
        np.maximum.accumulate(idx, out=idx)
        first = int(np.argmax(ok))
        idx[:first] = first
        out[:, j] = col[idx]
    return out


def _split_on(data: np.ndarray, speed_cols: list[int], tops: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) row ranges where the engine is on (not ``engine_off``: some speed >= 5 % of
    its maximum ``tops``).

    A dropout of a speed holds its last value, so it cannot fake a shutdown.
    """
    if not speed_cols:
        return [(0, len(data))]
    off = engine_off(_ffill(data[:, speed_cols]), tops)
    on = np.concatenate([[False], ~off, [False]])
    edges = np.flatnonzero(np.diff(on.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def read_runs(
    path: Source,
    channels: Sequence[str] | None = None,
    stats: ReadStats | None = None,
    sha256: bool = False,
) -> list[Run]:
    """The pass-off runs of a recording's sensor streams, in time order.

    channels: the columns wanted (default: every sensor channel found, contract
    order first). Runs are split at gaps >= 60 s and where every shaft speed is
    below 5 % of its maximum over the file; those off samples are dropped.
    shutdown_before = first "on" sample of the run - (last "on" sample of the
    previous run + 1/40 s). Several beds in one file give separate runs.
    sha256: also the file's hash into ``stats.sha256``, from the same read.
    """
    stats = stats if stats is not None else ReadStats()
    by_topic = read_payloads(path, stats, sha256)
    per_bed: dict[str, dict[str, list[bytes]]] = {}
    for topic, payloads in by_topic.items():
        parsed = parse_sensor_key(topic)
        if parsed is None:
            stats.unknown_topics.add(topic)
            continue
        per_bed.setdefault(parsed[0], {}).setdefault(parsed[1], []).extend(payloads)
    runs: list[Run] = []
    for bed in sorted(per_bed):
        runs += _bed_runs(bed, per_bed[bed], channels, stats)
    runs.sort(key=lambda r: r.t[0])
    return runs


def _bed_runs(
    bed: str,
    streams: dict[str, list[bytes]],
    wanted: Sequence[str] | None,
    stats: ReadStats,
) -> list[Run]:
    names = _order_channels(list(streams), wanted)
    col_of = {c: j for j, c in enumerate(names)}
    ts, vs, cs = [], [], []
    speed_names = [c for c in SPEED_CHANNELS if c in streams]
    extra = [c for c in speed_names if c not in col_of]
    for j, c in enumerate(list(names) + extra):  # speeds needed for splitting even if unwanted
        if c not in streams:
            continue
        t, v, ok = decode_samples(streams[c])
        stats.malformed += int(np.count_nonzero(~ok))
        t, v = t[ok], v[ok]
        ts.append(t)
        vs.append(v)
        cs.append(np.full(len(t), j, dtype=np.int64))
    if not ts:
        return []
    t, v, col = np.concatenate(ts), np.concatenate(vs), np.concatenate(cs)
    if not len(t):
        return []
    width = len(names) + len(extra)
    all_names = list(names) + extra
    speed_cols = [all_names.index(c) for c in speed_names]
    tops = np.array([np.nanmax(v[col == j]) if np.any(col == j) else np.nan for j in speed_cols])
    tops = np.where(np.isfinite(tops) & (tops > 0), tops, np.inf)

    order = np.argsort(t, kind="stable")  # t, v, col stay in recorded order, channel by channel
    cuts = run_starts(t[order])
    runs: list[Run] = []
    last_on_end: float | None = None
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(t)]]), strict=True):
        mine = np.sort(order[a:b])  # this run's samples, each channel's in recorded order
        k0, data = _align(t[mine], col[mine], v[mine], width)
        for r0, r1 in _split_on(data, speed_cols, tops[: len(speed_cols)]):
            if (r1 - r0) / FS < MIN_RUN:
                continue
            start = (k0 + r0) / FS
            shutdown = None if last_on_end is None else start - last_on_end
            runs.append(
                Run(
                    t=np.arange(k0 + r0, k0 + r1) / FS,
                    data=np.ascontiguousarray(data[r0:r1, : len(names)]),
                    channels=names,
                    bed=bed,
                    shutdown_before=shutdown,
                )
            )
            last_on_end = (k0 + r1) / FS
    return runs
