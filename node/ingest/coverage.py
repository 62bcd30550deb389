"""Whether every mapped channel covers the file's span: a cut file or a short channel is found
here, before anything is written. Pure numerics on the read ``Series``, no I/O.

The file's span is from the earliest first sample to the latest last sample of the mapped
channels. A channel is short when it holds no sample, fewer samples than its file declares
(an MDF4 channel group's cycle count), or starts later or ends earlier than that span by more
than its tolerance: the widest step interpolated over (``max_gap``, default 1 s) or two of its
own sample steps, whichever is larger (so channels of their own rates and start times pass).
A file its reader saw end early (npTDMS on a cut TDMS file) is short as a whole.

Without ``allow_partial`` the first short channel (or the cut file) is one ``OrdervibError``
line naming the file, the channel and the span it holds; with it, each channel's gap is
counted (seconds of the file's span it lacks, and 40 Hz slots) for the summary and the
recording's metadata.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from node.contract import FS, OrdervibError
from node.ingest.sources import Series


@dataclass
class ChannelReport:
    """One contract channel of an import: where it came from, what it held, what was written.

    source: the source channel's name; unit: the unit its values were read in ("" for none, or
    "scale" for the map's scale and offset); rate: Hz, its median sample rate (0 below two
    samples); first, last: s since the epoch of its first and last source sample (None: none);
    samples: source samples read; declared: what its file declares (None: unsaid); written:
    40 Hz samples written (nulls among them); missing_s, missing_slots: the file's span it lacks
    (a partial import); note: how its samples were picked (a CSV column's blanks)."""

    channel: str
    source: str
    unit: str = ""
    rate: float = 0.0
    first: float | None = None
    last: float | None = None
    samples: int = 0
    declared: int | None = None
    written: int = 0
    nulls: int = 0
    missing_s: float = 0.0
    missing_slots: int = 0
    note: str = ""


def span_text(a: float, b: float, origin: float) -> str:
    """A span in s from ``origin``: "0.0 s to 26.2 s".

    >>> span_text(1000.0, 1026.25, 1000.0)
    '0.0 s to 26.2 s'
    """
    return f"{a - origin:.1f} s to {b - origin:.1f} s"


def _slots(a: float, b: float) -> int:
    """40 Hz slots in [a, b] (s since the epoch)."""
    return max(math.floor(b * FS) - math.ceil(a * FS) + 1, 0)


def _step(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.0


def channel_reports(series: dict[str, Series], sources: dict[str, str]) -> dict[str, ChannelReport]:
    """Each channel's ``ChannelReport`` (source name, rate, span, counts; no gap yet), map order.
    ``sources``: contract channel -> source name."""
    out = {}
    for ch, name in sources.items():
        s = series[ch]
        step = _step(s.t)
        out[ch] = ChannelReport(channel=ch, source=name, rate=1.0 / step if step > 0 else 0.0,
                                first=float(s.t[0]) if len(s.t) else None,
                                last=float(s.t[-1]) if len(s.t) else None,
                                samples=len(s.t), declared=s.declared, note=s.note)
    return out


def check_coverage(path: str, reports: dict[str, ChannelReport], gaps: dict[str, float],
                   ends_early: str | None, allow_partial: bool) -> list[str]:
    """Count each channel's gap into ``reports``; the partial import's notes (one per short
    channel, and the cut file), [] when the file is whole. One-line ``OrdervibError`` for the
    first short channel, or the cut file, unless ``allow_partial``."""
    held = [r for r in reports.values() if r.first is not None]
    if not held:
        raise OrdervibError(f"{path}: no mapped channel holds a sample"
                            + (f" (the file ends early: {ends_early})" if ends_early else ""))
    a = min(r.first for r in held if r.first is not None)
    b = max(r.last for r in held if r.last is not None)
    notes = []
    for r in reports.values():
        why = _short(r, a, b, gaps[r.channel])
        if why is None:
            continue
        what = f"channel {r.source!r} (for {r.channel}) {why}"
        if not allow_partial:
            cut = f"; the file ends early ({ends_early})" if ends_early else ""
            raise OrdervibError(f"{path}: {what}{cut}: the file was cut or the channel stops short; "
                                "--allow-partial imports what there is, the gap counted")
        notes.append(f"{r.channel}: {why}, {r.missing_s:.1f} s ({r.missing_slots} samples at "
                     f"{FS:g} Hz) missing")
    if ends_early:
        if not allow_partial:
            spans = ", ".join(f"{r.channel} {span_text(r.first, r.last, a)}" for r in held
                              if r.first is not None and r.last is not None)
            raise OrdervibError(f"{path}: the file ends early ({ends_early}); it holds {spans}: "
                                "--allow-partial imports what it holds")
        notes.append(f"the file ends early ({ends_early}): what followed its last sample is unknown")
    return notes


def _short(r: ChannelReport, a: float, b: float, gap: float) -> str | None:
    """Why channel ``r`` is short of the file's span [a, b] (its gap counted into ``r``), None
    if it is not."""
    if r.first is None or r.last is None:
        r.missing_s, r.missing_slots = b - a, _slots(a, b)
        return f"holds no sample of the file's {span_text(a, b, a)}"
    step = 1.0 / r.rate if r.rate > 0 else 0.0
    tol = max(gap, 2.0 * step)
    late, early = r.first - a, b - r.last
    if late > tol or early > tol:
        r.missing_s = late + early
        r.missing_slots = _slots(a, b) - _slots(r.first, r.last)
        return f"holds {span_text(r.first, r.last, a)} of the file's {span_text(a, b, a)}"
    if r.declared is not None and r.samples < r.declared:
        r.missing_s = (r.declared - r.samples) * step
        r.missing_slots = round(r.missing_s * FS)
        return (f"holds {r.samples} of the {r.declared} samples its file declares "
                f"({span_text(r.first, r.last, a)})")
    return None
