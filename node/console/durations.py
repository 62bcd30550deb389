"""Short human durations for status lines."""

from __future__ import annotations


def duration_text(s: float) -> str:
    """A short human duration: '42 s', '3 min 05 s', '2 h 07 min'.

    >>> duration_text(42.4), duration_text(185.0), duration_text(7620.0)
    ('42 s', '3 min 05 s', '2 h 07 min')
    """
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"
