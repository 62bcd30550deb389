"""The live view: a running node's topics (and the test bed's sensors) streamed to Rerun.

``ordervib view --connect ENDPOINT`` subscribes to ``testbed/*/sensor/**`` and
``testbed/*/monitor/**``, keeps every payload by topic, and once per refresh builds the very
``ViewData`` the file view builds from a recording (``replay.views.view_data.view_data_of``): the
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

from node.contract import (
    ORDER_CHANNELS,
    PHASE_CHANNELS,
    SPEED_CHANNELS,
    OrdervibError,
    parse_sensor_key,
    phase_channel,
)
from replay.views.view_data import TIME_SERIES

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from replay.views.view_data import ViewData

# the sensor channels a view can draw (its speed, its target and the target's phase); the
# other channels' payloads are not kept (each refresh decodes everything kept)
_DRAWN = frozenset((*SPEED_CHANNELS, *ORDER_CHANNELS, *PHASE_CHANNELS))

PLOTS_EVERY_S = 5.0  # the 2-D views are logged again at most this often (each time all of them)


class LiveView:
    """Payloads by topic, added from the Zenoh callback thread; ``refresh`` logs what is new.

    Memory and each refresh's decoding: every payload kept, the monitor topics' and the
    sensor channels a view draws (``_DRAWN``, and --switch / --target), some 10^5 per
    channel over a pass-off run.
    """

    def __init__(self, bed: str | None = None, target: str | None = None, switch: str | None = None,
                 schedule: Schedule | None = None) -> None:
        self.bed, self.target, self.switch, self.schedule = bed, target, switch, schedule
        self._asked = {c for c in (switch, target, target and phase_channel(target)) if c}  # kept too
        self._lock = threading.Lock()
        self._by_topic: dict[str, list[bytes]] = defaultdict(list)
        self.received = 0
        self._logged = dict.fromkeys(TIME_SERIES, -math.inf)  # last time logged, per time series
        self.data: ViewData | None = None  # the last refresh's view of everything received
        self.source = "none"
        self._blueprint_sent = False
        self._plots_at = -math.inf  # monotonic time the 2-D views were last logged

    def add(self, key: str, payload: bytes) -> None:
        """One received message (any thread); a sensor channel the view cannot draw is only
        counted (its topic listed: the beds are picked from the topics)."""
        sensor = parse_sensor_key(key)
        keep = sensor is None or sensor[1] in _DRAWN or sensor[1] in self._asked
        with self._lock:
            topic = self._by_topic[key]
            if keep:
                topic.append(payload)
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

        from replay.views.rerun_view import Clock, blueprint, log_plots, log_series
        from replay.views.view_data import rows_after, view_data_of

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
        for part in TIME_SERIES:
            series = getattr(new, part)
            if series is not None and len(series.t):
                self._logged[part] = float(series.t[-1])
        self.data = data
        return counts
