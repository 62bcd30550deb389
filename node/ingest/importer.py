"""``import_file``: a test cell's recording, read as its map says, as a contract recording.

Everything is read and checked before the output is touched: the map (``mapping.load_map``),
the file's format (``sources.source_format``), then every mapped channel (``read_source``,
``check_series``: its times; its unit against the file's), then whether every channel covers
the file's span (``coverage.check_coverage``: a cut file or a short channel is an error, or
with ``allow_partial`` a gap counted). Then each channel is converted to the contract's unit
and put on the 40 Hz grid (``resample.to_grid``), and all are written (``write.write_grid``)
with a metadata record ``ordervib.import`` saying what was read (``import_metadata``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO

import numpy as np
import orjson

from node.contract import FS, OrdervibError, is_phase_channel, run_starts
from node.contract.payload import T_MAX
from node.ingest.coverage import ChannelReport, channel_reports, check_coverage
from node.ingest.mapping import ImportMap, load_map
from node.ingest.resample import grid_size, to_grid
from node.ingest.sources import Series, read_source, source_format
from node.ingest.write import write_grid

log = logging.getLogger(__name__)

T_EARLIEST = 1e8  # s since the epoch (1973): an earlier absolute time is a relative time mistaken
MAX_SLOTS = 20_000_000  # 40 Hz samples written per channel at most (139 h)
METADATA_NAME = "ordervib.import"  # the recording's metadata record of what an import read


@dataclass
class ImportReport:
    """What an import wrote: per contract channel its ``ChannelReport`` (source, unit, rate,
    span, samples read and written, nulls, gap), the span written (s since the epoch), the runs
    by the contract's gap rule, the message count, and the partial import's notes ([]: whole)."""

    format: str
    channels: dict[str, ChannelReport] = field(default_factory=dict)
    first: float | None = None
    last: float | None = None
    stretches: int = 0
    messages: int = 0
    partial: list[str] = field(default_factory=list)

    @property
    def samples(self) -> dict[str, int]:
        """40 Hz samples written per channel."""
        return {c: r.written for c, r in self.channels.items()}

    @property
    def nulls(self) -> dict[str, int]:
        """Null samples among them per channel."""
        return {c: r.nulls for c, r in self.channels.items()}


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


def plan_channels(path: str, imap: ImportMap, series: dict[str, Series],
                  reports: dict[str, ChannelReport]) -> list[tuple]:
    """Check every mapped channel (times, unit, size) before any is resampled, so a bad one ends
    the command before any status line: (map entry, series, scale, offset, max_gap) per channel
    that holds samples, map order. Each report gets the unit read."""
    plan = []
    for cm in imap.channels:
        s = series[cm.channel]
        where = f"{path}: channel {cm.source!r} (for {cm.channel})"
        if len(s.t):
            check_series(s, where)
        try:
            scale, offset = cm.affine(s.unit)
            unit = cm.source_unit(s.unit)
        except OrdervibError as exc:
            raise OrdervibError(f"{where}: {exc}") from None
        reports[cm.channel].unit = "scale" if cm.scale is not None else (unit or "")
        gap = cm.max_gap if cm.max_gap is not None else imap.time.max_gap
        size = grid_size(s.t, max_gap=gap)
        if size > MAX_SLOTS:
            raise OrdervibError(f"{where}: {size} samples at {FS:g} Hz, more than {MAX_SLOTS} per channel")
        if len(s.t):
            plan.append((cm, s, scale, offset, gap))
    return plan


def import_file(path: str, imap: ImportMap, fmt: str, out: str | os.PathLike | IO[bytes],
                progress: Callable[[float], None] | None = None, *,
                allow_partial: bool = False) -> ImportReport:
    """Read ``path`` (format ``fmt``, checked by ``source_format``) as ``imap`` says and write the
    contract recording to ``out``; nothing is written when reading or checking fails. A cut file
    or a short channel fails unless ``allow_partial`` (then its gap is counted in the report)."""
    log.debug("reading %s (%s, %.1f MB): %d channels", path, fmt, os.path.getsize(path) / 1e6,
              len(imap.channels))
    source = read_source(path, fmt, imap)
    series = source.series
    reports = channel_reports(series, {cm.channel: cm.source for cm in imap.channels})
    plan = plan_channels(path, imap, series, reports)
    gaps = {cm.channel: cm.max_gap if cm.max_gap is not None else imap.time.max_gap for cm in imap.channels}
    report = ImportReport(format=fmt, channels=reports)
    report.partial = check_coverage(path, reports, gaps, source.ends_early, allow_partial)
    for note in report.partial:
        log.warning("%s: partial import: %s", path, note)
    names, grids = [], []
    for cm, s, scale, offset, gap in plan:
        k, x = to_grid(s.t, s.v * scale + offset, max_gap=gap, phase=is_phase_channel(cm.channel))
        r = reports[cm.channel]
        r.written, r.nulls = len(k), int(np.isnan(x).sum())
        log.info("%s <- %s: %d samples at %g Hz (%d null)%s", cm.channel, cm.source, len(k), FS,
                 r.nulls, "" if scale == 1 and offset == 0 else f", x {scale:.6g} + {offset:.6g}")
        names.append(cm.channel)
        grids.append((k, x))
    del series, plan
    slots = np.unique(np.concatenate([k for k, _ in grids])) if grids else np.empty(0, np.int64)
    if len(slots) == 0:
        raise OrdervibError(f"{path}: no sample to write (every source shorter than one 40 Hz step?)")
    report.first, report.last = float(slots[0] / FS), float(slots[-1] / FS)
    report.stretches = len(run_starts(slots / FS)) + 1
    report.messages = write_grid(out, imap.bed, names, grids, progress,
                                 metadata=(METADATA_NAME, import_metadata(path, imap, report,
                                                                          source.ends_early)))
    return report


def import_metadata(path: str, imap: ImportMap, report: ImportReport,
                    ends_early: str | None) -> dict[str, str]:
    """The ``ordervib.import`` metadata record: the file's name (no folder) and format, the bed,
    whether the import is partial (and why), and per channel a JSON object of its report."""
    meta = {"file": os.path.basename(path), "format": report.format, "bed": imap.bed,
            "partial": "true" if report.partial else "false"}
    if report.partial:
        meta["partial_notes"] = orjson.dumps(report.partial).decode()
    if ends_early:
        meta["ends_early"] = ends_early
    for ch, r in report.channels.items():
        meta[f"channel.{ch}"] = orjson.dumps({
            "source": r.source, "unit": r.unit, "rate_hz": float(f"{r.rate:.5g}"), "first": r.first,
            "last": r.last, "samples": r.samples, "declared": r.declared, "written": r.written,
            "nulls": r.nulls, "missing_s": round(r.missing_s, 6), "missing_samples": r.missing_slots,
            "note": r.note}).decode()
    return meta
