"""``import_file``: a test cell's recording, read as its map says, as a contract recording.

Everything is read and checked before the output is touched: the map (``mapping.load_map``),
the file's format (``sources.source_format``), then every mapped channel (``read_source``,
``check_series``). Then each channel is converted to the contract's unit and put on the 40 Hz
grid (``resample.to_grid``), and all are written (``write.write_grid``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO

import numpy as np

from node.contract import FS, OrdervibError, is_phase_channel, run_starts
from node.contract.payload import T_MAX
from node.ingest.mapping import ImportMap, load_map
from node.ingest.resample import grid_size, to_grid
from node.ingest.sources import Series, read_source, source_format
from node.ingest.write import write_grid

log = logging.getLogger(__name__)

T_EARLIEST = 1e8  # s since the epoch (1973): an earlier absolute time is a relative time mistaken
MAX_SLOTS = 20_000_000  # 40 Hz samples written per channel at most (139 h)


@dataclass
class ImportReport:
    """What an import wrote: samples (and nulls among them) per contract channel, the span
    (s since the epoch), the runs by the contract's gap rule, the message count."""

    format: str
    samples: dict[str, int] = field(default_factory=dict)
    nulls: dict[str, int] = field(default_factory=dict)
    first: float | None = None
    last: float | None = None
    stretches: int = 0
    messages: int = 0


def read_map_and_source(path: str, map_path: str, fmt: str | None = None) -> tuple[ImportMap, str]:
    """The checked map and the file's format (``fmt`` overrides the map's and the suffix's)."""
    imap = load_map(map_path)
    return imap, source_format(path, fmt or imap.format)


def check_series(s: Series, where: str) -> None:
    """One-line ``OrdervibError`` unless the times are finite, strictly increasing and absolute."""
    t = s.t
    if len(t) == 0:
        raise OrdervibError(f"{where}: no samples")
    if not np.isfinite(t).all():
        raise OrdervibError(f"{where}: a time that is no number")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise OrdervibError(f"{where}: times not increasing at sample {i} ({t[i - 1]!r} then {t[i]!r} s)")
    if t[0] < T_EARLIEST or t[-1] >= T_MAX:
        raise OrdervibError(f"{where}: times from {t[0]:.6g} s since the epoch: relative times need "
                            "[time] start in the map")


def grid_channels(imap: ImportMap, series: dict[str, Series]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each mapped channel in the contract's unit on the 40 Hz grid, map order: (k, x) pairs.
    Every channel is checked (times, unit, size) before the first is resampled, so a bad one
    ends the command before any status line."""
    plan = []
    for cm in imap.channels:
        s = series[cm.channel]
        where = f"{cm.source!r} (for {cm.channel})"
        check_series(s, where)
        scale, offset = cm.affine(s.unit)
        gap = cm.max_gap if cm.max_gap is not None else imap.time.max_gap
        size = grid_size(s.t, max_gap=gap)
        if size > MAX_SLOTS:
            raise OrdervibError(f"{where}: {size} samples at {FS:g} Hz, more than {MAX_SLOTS} per channel")
        plan.append((cm, s, scale, offset, gap))
    out = []
    for cm, s, scale, offset, gap in plan:
        k, x = to_grid(s.t, s.v * scale + offset, max_gap=gap, phase=is_phase_channel(cm.channel))
        log.info("%s <- %s: %d samples at %g Hz (%d null)%s", cm.channel, cm.source, len(k), FS,
                 int(np.isnan(x).sum()), "" if scale == 1 and offset == 0 else
                 f", x {scale:.6g} + {offset:.6g}")
        out.append((k, x))
    return out


def import_file(path: str, imap: ImportMap, fmt: str, out: str | os.PathLike | IO[bytes],
                progress: Callable[[float], None] | None = None) -> ImportReport:
    """Read ``path`` (format ``fmt``, checked by ``source_format``) as ``imap`` says and write the
    contract recording to ``out``; nothing is written when reading or checking fails."""
    log.debug("reading %s (%s, %.1f MB): %d channels", path, fmt, os.path.getsize(path) / 1e6,
             len(imap.channels))
    series = read_source(path, fmt, imap)
    grids = grid_channels(imap, series)
    del series
    report = ImportReport(format=fmt)
    names = [cm.channel for cm in imap.channels]
    for name, (k, x) in zip(names, grids, strict=True):
        report.samples[name] = len(k)
        report.nulls[name] = int(np.isnan(x).sum())
    slots = np.unique(np.concatenate([k for k, _ in grids]))
    if len(slots) == 0:
        raise OrdervibError(f"{path}: no sample to write (every source shorter than one 40 Hz step?)")
    report.first, report.last = float(slots[0] / FS), float(slots[-1] / FS)
    report.stretches = len(run_starts(slots / FS)) + 1
    report.messages = write_grid(out, imap.bed, names, grids, progress)
    return report
