"""Messages in, messages out: the node's logic over every test bed, without I/O.

``NodeCore.handle(key, payload)`` takes one sensor message as it arrived (key
expression and raw JSON bytes) and returns the monitor messages it completes.
Bad payloads are counted and skipped; unknown keys and channels are ignored.
The live node and ``ordervib replay`` both drive this class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import orjson

from node.align import Aligner
from node.bundle import Bundle
from node.pipeline import MonitorPipeline
from node.recording import parse_sensor_key


@dataclass
class BedState:
    aligner: Aligner
    pipeline: MonitorPipeline
    alarms: int = 0


@dataclass
class CoreStats:
    messages: int = 0
    malformed: int = 0
    foreign: int = 0  # keys that are not sensor keys
    published: int = 0
    beds: dict[str, BedState] = field(default_factory=dict)


Output = tuple[str, dict]  # (key expression, JSON-ready message)


class NodeCore:
    def __init__(self, bundle: Bundle) -> None:
        self.bundle = bundle
        self.stats = CoreStats()

    def _bed(self, bed: str) -> BedState:
        st = self.stats.beds.get(bed)
        if st is None:
            pipe = MonitorPipeline(self.bundle)
            st = BedState(Aligner(pipe.channels), pipe)
            self.stats.beds[bed] = st
        return st

    def handle(self, key: str, payload: bytes) -> list[Output]:
        """One incoming message; returns the monitor messages it completes (in order)."""
        self.stats.messages += 1
        parsed = parse_sensor_key(key)
        if parsed is None:
            self.stats.foreign += 1
            return []
        bed, channel = parsed
        try:
            d = orjson.loads(payload)
            t = d["t"]
            v = d["v"]
            ok = isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)
            ok = ok and (v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)))
        except (orjson.JSONDecodeError, TypeError, KeyError):
            ok = False
        if not ok:
            self.stats.malformed += 1
            return []
        st = self._bed(bed)
        return self._run(bed, st, st.aligner.push(channel, float(t), None if v is None else float(v)))

    def _run(self, bed: str, st: BedState, samples) -> list[Output]:
        out: list[Output] = []
        target = self.bundle.target
        for s in samples:
            msg, oc_msg = st.pipeline.step(s)
            if oc_msg is not None:
                out.append((f"testbed/{bed}/monitor/oc", oc_msg))
            if msg["flag"] == "alarm":
                st.alarms += 1
            out.append((f"testbed/{bed}/monitor/{target}", msg))
        self.stats.published += len(out)
        return out

    def finish(self) -> list[Output]:
        """End of stream: emit every sample still waiting for late channels."""
        out: list[Output] = []
        for bed, st in self.stats.beds.items():
            out += self._run(bed, st, st.aligner.flush())
        return out

    def health(self, bed: str, t: float, extra: dict | None = None) -> dict:
        st = self.stats.beds[bed]
        a = st.aligner.stats
        return {"t": t, "samples": a.samples, "late": a.late, "duplicates": a.duplicates,
                "missing": dict(a.missing), "malformed": self.stats.malformed,
                "alarm_samples": st.alarms, **(extra or {})}
