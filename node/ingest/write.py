"""Grid samples of several channels into a recording, in the contract's layout (sections 1, 3).

One message per slot and channel, ``{"t": k / FS, "v": value or null}`` on
``testbed/<bed>/sensor/<channel>``, in time order (a slot's channels in contract order), through
``node.mcap.RecordingWriter`` (chunk and message indexes, summary). ``log_time`` is the
sample's t; ``publish_time`` (when it was received) is the same: a file has no receive time.
A metadata record (what the import read) follows the last chunk.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import IO

import numpy as np
import orjson

from node.contract import FS, log_times_ns, sensor_key
from node.mcap import RecordingWriter

BLOCK = 100_000  # messages encoded and handed to the writer at a time


def write_grid(out: str | os.PathLike | IO[bytes], bed: str, channels: Sequence[str],
               grids: Sequence[tuple[np.ndarray, np.ndarray]],
               progress: Callable[[float], None] | None = None,
               metadata: tuple[str, dict[str, str]] | None = None) -> int:
    """Write each channel's (k (m,) int64 slots, x (m,) values, NaN for null) to ``out``;
    returns the message count. ``progress``: called with the fraction written; ``metadata``:
    (name, string pairs) of a metadata record written with them."""
    keys = [sensor_key(bed, c) for c in channels]
    k = np.concatenate([g[0] for g in grids]) if grids else np.empty(0, np.int64)
    x = np.concatenate([g[1] for g in grids]) if grids else np.empty(0)
    col = np.concatenate([np.full(len(g[0]), j, np.int64) for j, g in enumerate(grids)]) \
        if grids else np.empty(0, np.int64)
    order = np.lexsort((col, k))
    total = len(order)
    dumps = orjson.dumps
    with RecordingWriter(out, background=True) as writer:
        for key in keys:  # every channel registered up front, in contract order
            writer.channel_id(key)
        for a in range(0, total, BLOCK):
            sel = order[a:a + BLOCK]
            t = k[sel] / FS
            ns = log_times_ns(t)
            vs = [None if v != v else v for v in x[sel].tolist()]
            payloads = [dumps({"t": ti, "v": vi}) for ti, vi in zip(t.tolist(), vs, strict=True)]
            writer.write_columns([keys[j] for j in col[sel].tolist()], ns, ns, payloads)
            if progress is not None:
                progress(min(a + BLOCK, total) / max(total, 1))
        if metadata is not None:
            writer.add_metadata(*metadata)
    return total
