"""The lines ``ordervib import`` prints on success: what was written, then per channel its
source name, unit, rate, span and samples, then the partial import's gaps (if any)."""

from __future__ import annotations

import datetime as dt

from node.contract import FS
from node.ingest.importer import ImportReport


def _utc(t: float) -> str:
    return dt.datetime.fromtimestamp(t, tz=dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")[:-4] + "Z"


def summary_lines(path: str, out: str, bed: str, report: ImportReport, took: float) -> list[str]:
    """The summary: a head line, a table (one row per contract channel; span in s from the
    recording's first sample), the partial import's notes."""
    first, last = report.first or 0.0, report.last or 0.0
    lines = [f"import: {path} ({report.format}) -> {out}: {report.messages} messages on "
             f"{sum(1 for r in report.channels.values() if r.written)} channels of bed {bed}, "
             f"{last - first:.1f} s from {_utc(first)} in {report.stretches} stretch(es) apart by "
             f"60 s or more, in {took:.1f} s" + ("; PARTIAL (--allow-partial)" if report.partial else "")]
    rows = [("channel", "source", "unit", "rate Hz", "span s", "samples", f"at {FS:g} Hz", "null",
             "missing s")]
    for ch, r in report.channels.items():
        span = "-" if r.first is None or r.last is None else f"{r.first - first:.1f} to {r.last - first:.1f}"
        samples = f"{r.samples}" + (f" of {r.declared}" if r.declared is not None and r.declared != r.samples
                                    else "")
        rows.append((ch, r.source, r.unit or "-", f"{r.rate:.4g}", span, samples, str(r.written),
                     str(r.nulls), f"{r.missing_s:.1f}" if r.missing_s else "-"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        lines.append("  " + "  ".join(c.ljust(w) if i < 3 else c.rjust(w)
                                      for i, (c, w) in enumerate(zip(row, widths, strict=True))).rstrip())
    lines += [f"  {r.channel}: {r.note}" for r in report.channels.values() if r.note]
    lines += [f"  partial: {note}" for note in report.partial]
    return lines
