"""``ordervib import``: a test cell's own recording (ASAM MDF4, NI TDMS or CSV) as a contract
recording, as its map says (``docs/import.md``; the work is ``node.ingest``).

The map, the file and the output name are checked first, then every mapped channel is read
and checked; only then is the output written, under a temporary name renamed at the end. An
existing output is never replaced unless ``--force``. A cut file or a short channel is an
error unless ``--allow-partial``. The summary (stdout) is ``node.ingest.summary_lines``.
"""

from __future__ import annotations

import argparse
import logging
import time

from node.cli.logs import Progress
from node.cli.outputs import check_output, replacing
from node.ingest import import_file, read_map_and_source, summary_lines
from node.ingest.mapping import FORMATS

log = logging.getLogger(__name__)

NAME = "import"
HELP = "a test cell's recording (ASAM MDF4 .mf4, NI TDMS .tdms or CSV) as a contract MCAP recording"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="the test cell's recording: .mf4, .tdms or .csv")
    p.add_argument("--map", required=True, metavar="MAP.toml",
                   help="which source channel is which contract channel, units, clock, bed "
                        "(docs/import.md)")
    p.add_argument("--out", required=True, metavar="REC.mcap", help="the contract recording to write")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="the file's format (default: the map's format, else the file's suffix)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--allow-partial", action="store_true",
                   help="import a file that ends early, or a channel shorter than the others, with "
                        "the gap counted in the summary and the recording's metadata (default: an error)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success, no progress")


def run(args: argparse.Namespace) -> int:
    imap, fmt = read_map_and_source(args.file, args.map, args.format)
    check_output(args.out, "--out", suffix=".mcap", inputs=[args.file, args.map], replace=False,
                 force=args.force)
    start = time.perf_counter()
    with replacing(args.out, overwrite=args.force) as part:
        report = import_file(args.file, imap, fmt, part, Progress(NAME, log),
                             allow_partial=args.allow_partial)
    if not args.quiet:
        for line in summary_lines(args.file, args.out, imap.bed, report, time.perf_counter() - start):
            print(line)
    return 0
