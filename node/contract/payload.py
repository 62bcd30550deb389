"""The sensor payload rule (``docs/contract.md`` section 1), in one scalar and one batch form.

A sensor payload is a UTF-8 JSON object ``{"t": <number>, "v": <number or null>}``
(further fields are ignored). It is *well formed* when ``t`` is a finite number
(not a boolean) in ``[T_MIN, T_MAX)`` -- a time the recording can store as unsigned
nanoseconds -- and ``v`` is a finite number (not a boolean) or null. Anything else
(bad bytes, bad JSON, a missing field, a string, an out-of-range time) is malformed:
counted by the caller, never aligned.

>>> decode_sample(b'{"t": 1700000000.0, "v": 2.5}')
(1700000000.0, 2.5)
>>> decode_sample(b'{"t": 1700000000, "v": null}')
(1700000000.0, None)
>>> decode_sample(b'{"t": -1.0, "v": 2.5}') is None, decode_sample(b'{"t": true, "v": 1}') is None
(True, True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import itemgetter

import numpy as np
import orjson

T_MIN = 0.0  # s since the Unix epoch
T_MAX = 2.0**63 / 1e9  # s: log_time = round(t * 1e9) must fit a signed 64-bit nanosecond count

_T, _V = itemgetter("t"), itemgetter("v")
_FLOAT_OR_NULL = frozenset((float, type(None)))
_ERRORS = (orjson.JSONDecodeError, TypeError, KeyError, IndexError)


def log_time_ns(t: float) -> int:
    """The recordings' ``log_time`` of a message of time t (s): integer nanoseconds (section 3)."""
    return round(t * 1e9)


def log_times_ns(t: np.ndarray) -> np.ndarray:
    """``log_time_ns`` of each time t (K,) s at once: int64 (K,), the same integers (both round
    half to even).

    >>> t = [1.5e-9, 2.5e-9, 1767600000.025]
    >>> log_times_ns(np.array(t)).tolist() == [log_time_ns(x) for x in t] == [2, 2, 1767600000025000192]
    True
    """
    return np.rint(np.asarray(t, float) * 1e9).astype(np.int64)


def check_sample(t: object, v: object) -> tuple[float, float | None] | None:
    """(t, v) as floats when they make a well-formed sample (see the module); else None."""
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        return None
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
        return None
    try:
        tf = float(t)
        vf = None if v is None else float(v)
    except OverflowError:  # an integer too large for a float
        return None
    if not (T_MIN <= tf < T_MAX) or (vf is not None and not math.isfinite(vf)):
        return None
    return tf, vf


def decode_sample(payload: bytes) -> tuple[float, float | None] | None:
    """(t, v) of one sensor payload; None when it is malformed."""
    try:
        d = orjson.loads(payload)
        return check_sample(d["t"], d["v"])
    except _ERRORS:
        return None


def decode_list(payloads: Sequence[bytes]) -> tuple[list[float], list[float], list[bool]]:
    """``decode_samples`` as Python lists, for a few payloads (no numpy call): the very same
    values (the common batch without a per-message check, any other message by message).

    >>> decode_list([b'{"t": 1.5, "v": null}', b'{"t": -1.0, "v": 2.0}'])
    ([1.5, nan], [nan, nan], [True, False])
    """
    nan = math.nan
    try:
        ds = list(map(orjson.loads, payloads))
        ts, vs = list(map(_T, ds)), list(map(_V, ds))
        if set(map(type, ts)) <= {float} and _FLOAT_OR_NULL.issuperset(map(type, vs)):
            ok = [T_MIN <= x < T_MAX for x in ts]  # NaN cannot come from JSON, infinity neither
            if all(ok):
                return ts, [nan if x is None else x for x in vs], ok
            return ([x if good else nan for x, good in zip(ts, ok, strict=True)],
                    [nan if x is None or not good else x for x, good in zip(vs, ok, strict=True)], ok)
    except _ERRORS:
        pass
    t, v, oks = [], [], []
    for payload in payloads:
        s = decode_sample(payload)
        t.append(nan if s is None else s[0])
        v.append(nan if s is None or s[1] is None else s[1])
        oks.append(s is not None)
    return t, v, oks


def decode_samples(payloads: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``decode_sample`` over a batch: ``(t, v, ok)``, each of shape (n,).

    t, v: float64 (NaN where malformed; v NaN also for null); ok: bool, the payload is
    well formed. The common batch (every payload a float ``t`` and a float or null ``v``)
    is decoded without a per-message Python check.
    """
    n = len(payloads)
    try:
        ds = list(map(orjson.loads, payloads))
        ts, vs = list(map(_T, ds)), list(map(_V, ds))
        if set(map(type, ts)) <= {float} and _FLOAT_OR_NULL.issuperset(map(type, vs)):
            t = np.fromiter(ts, dtype=np.float64, count=n)
            v = np.fromiter((math.nan if x is None else x for x in vs), dtype=np.float64, count=n)
            ok = (t >= T_MIN) & (t < T_MAX)  # NaN cannot come from JSON, infinity neither
            t[~ok] = math.nan
            v[~ok] = math.nan
            return t, v, ok
    except _ERRORS:
        pass
    t, v, ok = np.full(n, math.nan), np.full(n, math.nan), np.zeros(n, dtype=bool)
    for i, payload in enumerate(payloads):
        s = decode_sample(payload)
        if s is not None:
            t[i] = s[0]
            v[i] = math.nan if s[1] is None else s[1]
            ok[i] = True
    return t, v, ok
