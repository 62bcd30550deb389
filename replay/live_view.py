"""The live view: a running node's topics (and the test bed's sensors) streamed to Rerun.

``ordervib view --connect ENDPOINT`` subscribes to ``testbed/*/sensor/**`` and
``testbed/*/monitor/**``, keeps every payload by topic, and once per refresh builds the very
``ViewData`` the file view builds from a recording (``replay.view_data.view_data_of``): the
time series get only their new stretch (``rows_after``), the 2-D views (characteristic curve,
polar, Bode) are logged again whole (they are static, so each replaces the last). The layout
is the file view's blueprint, sent once the first data tell what there is to show.

>>> v = LiveView()
>>> v.add("testbed/bed1/sensor/nB", b'{"t": 1.0, "v": 3000.0}')
>>> v.received, v.topics()
(1, ['testbed/bed1/sensor/nB'])
"""

from __future__ import annotations

import math
import threading
from collections import defaultdict
from typing import TYPE_CHECKING

from node.contract import OrdervibError

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from replay.view_data import ViewData

PARTS = ("speed", "measured", "monitor", "switches", "health", "order_phase")  # ViewData's time series
PLOTS_EVERY_S = 5.0  # the 2-D views are logged again at most this often (each time all of them)


class LiveView:
    """Payloads by topic, added from the Zenoh callback thread; ``refresh`` logs what is new.

    Memory: every payload received (a live pass-off run is some 10^5 messages per target).
    """

    def __init__(self, bed: str | None = None, target: str | None = None, switch: str | None = None,
                 schedule: Schedule | None = None) -> None:
        self.bed, self.target, self.switch, self.schedule = bed, target, switch, schedule
        self._lock = threading.Lock()
        self._by_topic: dict[str, list[bytes]] = defaultdict(list)
        self.received = 0
        self._logged = dict.fromkeys(PARTS, -math.inf)  # last time logged, per time series
        self.data: ViewData | None = None  # the last refresh's view of everything received
        self.source = "none"
        self._blueprint_sent = False
        self._plots_at = -math.inf  # monotonic time the 2-D views were last logged

    def add(self, key: str, payload: bytes) -> None:
        """One received message (any thread)."""
        with self._lock:
            self._by_topic[key].append(payload)
            self.received += 1

    def topics(self) -> list[str]:
        with self._lock:
            return sorted(self._by_topic)

    def refresh(self, final: bool = False) -> dict[str, int] | None:
        """Log what arrived since the last refresh into the current Rerun recording; the counts
        logged, or None while there is nothing to show yet (no speed of the bed). The 2-D views
        are logged again every ``PLOTS_EVERY_S`` and on the ``final`` refresh."""
        import time

        import rerun as rr

        from replay.rerun_view import Clock, blueprint, log_plots, log_series
        from replay.view_data import rows_after, view_data_of

        with self._lock:
            snapshot = {k: list(v) for k, v in self._by_topic.items()}
        if not snapshot:
            return None
        try:
            data, self.source = view_data_of(snapshot, self.bed, self.target, self.switch, self.schedule)
        except OrdervibError:  # not yet: no speed (or no target) of the bed received
            return None
        self.bed, self.target = data.bed, data.target  # keep watching the bed and target chosen
        if not self._blueprint_sent:
            rr.send_blueprint(blueprint(data))
            self._blueprint_sent = True
        clock = Clock(data.speed.t)
        new = rows_after(data, self._logged)
        counts = log_series(new, clock)
        if final or time.monotonic() - self._plots_at >= PLOTS_EVERY_S:
            counts.update(log_plots(data, clock))
            self._plots_at = time.monotonic()
        for part in PARTS:
            series = getattr(new, part)
            if series is not None and len(series.t):
                self._logged[part] = float(series.t[-1])
        self.data = data
        return counts
