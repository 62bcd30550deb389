"""Whether an ASAM MDF4 file ends before its own blocks do: a cut (or unfinished) file.

asammdf refuses such a file whole ("seek out of range", "incomplete block"), which does not
say that the file is cut, nor which channels are lost. ``cut_at`` walks the blocks a reader
needs (the header, the data-group list, each group's channel groups and data blocks, data
lists), reading only their 24-byte heads and links, and says which one runs past the end.
The walk is bounded (``MAX_BLOCKS``); past the bound the file is taken as whole.

Block layout (ASAM MDF 4.x): id (4 bytes, ``##XX``), reserved (4), length (u64), link count
(u64), the links (u64 file offsets, 0 for none), the block's data.
"""

from __future__ import annotations

import struct
from typing import IO

MAX_BLOCKS = 200_000  # block heads read at most
MAX_LINKS = 1 << 20  # links of one block at most (a data list of a million blocks)
HD_AT = 64  # the header block follows the 64-byte identification block
_HEAD = struct.Struct("<4s4xQQ")
_DATA = (b"##DT", b"##DZ", b"##SD", b"##RD", b"##DV", b"##DI", b"##RV", b"##RI")


class _Cut(Exception):
    """A block (or a link) past the file's end: the message says which."""


class _Blocks:
    """Heads and links of one MDF4 file's blocks, read on demand and checked against its size."""

    def __init__(self, f: IO[bytes], size: int) -> None:
        self.f, self.size, self.read = f, size, 0

    def head(self, off: int, what: str) -> tuple[bytes, list[int]]:
        """(block id, links) of the block at ``off``; ``_Cut`` when it runs past the end."""
        self.read += 1
        if self.read > MAX_BLOCKS:
            raise StopIteration
        if off + _HEAD.size > self.size:
            raise _Cut(f"{what} at byte {off:,} lies past it")
        self.f.seek(off)
        bid, length, n = _HEAD.unpack(self.f.read(_HEAD.size))
        if off + length > self.size:
            raise _Cut(f"{what} ({bid.decode('latin-1')}) at byte {off:,} runs to byte {off + length:,}")
        if n > MAX_LINKS or _HEAD.size + 8 * n > length:
            return bid, []  # no block of a reader's path: not ours to judge
        links = list(struct.unpack(f"<{n}Q", self.f.read(8 * n)))
        return bid, links

    def text(self, off: int) -> str:
        """A TX block's text (a channel's name), "" when there is none or it is cut."""
        if not off or off + _HEAD.size > self.size:
            return ""
        self.f.seek(off)
        bid, length, n = _HEAD.unpack(self.f.read(_HEAD.size))
        if bid != b"##TX" or off + length > self.size or length > 4096:
            return ""
        self.f.seek(off + _HEAD.size + 8 * n)
        raw = self.f.read(max(length - _HEAD.size - 8 * n, 0))
        return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def cut_at(path: str, size: int) -> str | None:
    """Why the MDF4 file at ``path`` (``size`` bytes) ends early, one clause naming the block and,
    for a data block, its channel group and channels; None when every block fits."""
    with open(path, "rb") as f:
        blocks = _Blocks(f, size)
        try:
            _, hd = blocks.head(HD_AT, "its header block")
            dg, group = (hd[0] if hd else 0), 0
            while dg:
                _, dgl = blocks.head(dg, f"the block of channel group {group}")
                cgs = _channel_groups(blocks, dgl[1] if len(dgl) > 1 else 0, group)
                try:
                    _data(blocks, dgl[2] if len(dgl) > 2 else 0, f"the data of channel group {group}")
                except _Cut as exc:
                    names = _names(blocks, cgs)
                    raise _Cut(f"{exc}" + (f" (channels {', '.join(names)})" if names else "")) from None
                dg, group = (dgl[0] if dgl else 0), group + 1
        except _Cut as exc:
            return f"at byte {size:,}, but {exc}"
        except StopIteration:  # more blocks than the bound: taken as whole
            return None
    return None


def _channel_groups(blocks: _Blocks, cg: int, group: int) -> list[list[int]]:
    """The links of each channel group block of a data group, checked."""
    out = []
    while cg:
        _, links = blocks.head(cg, f"the channel list of channel group {group}")
        out.append(links)
        cg = links[0] if links else 0
    return out


def _data(blocks: _Blocks, off: int, what: str) -> None:
    """Check a data group's data: one data block, or a (header and) data list of them."""
    while off:
        bid, links = blocks.head(off, what)
        if bid == b"##HL":
            off = links[0] if links else 0
            continue
        if bid != b"##DL":
            return  # a data block (or one this walk does not know): its head fitted
        for link in links[1:]:
            if link:
                blocks.head(link, what)
        off = links[0] if links else 0


def _names(blocks: _Blocks, cgs: list[list[int]]) -> list[str]:
    """The channel names of channel groups (at most 8), for the message; [] if unreadable."""
    names: list[str] = []
    try:
        for links in cgs:
            cn = links[1] if len(links) > 1 else 0
            while cn and len(names) < 8:
                bid, cnl = blocks.head(cn, "a channel")
                if bid != b"##CN" or len(cnl) < 3:
                    break
                names.append(blocks.text(cnl[2]))
                cn = cnl[0]
    except (_Cut, StopIteration):
        pass
    return [n for n in names if n]
