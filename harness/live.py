"""The live rig: test beds published over Zenoh on loopback, their replies timed.

* :func:`load_stream` -- one test bed's messages of a recording, slot by slot (40 Hz);
* :class:`Bench` -- this process's Zenoh session: publishes the beds at 40 Hz in real time and
  stamps every reply on arrival; :func:`latencies` turns the stamps into per-sample latencies;
* :func:`start_node` / :func:`stop_node` -- ``ordervib run`` as a separate process;
* :func:`start_peer` / :func:`stop_peer` -- a bare Zenoh process (``python -m harness.live --peer``)
  that echoes one message per complete sample or only counts: the ceiling a node is set beside;
  ``relay`` takes the node's intake and output path without its logic (:func:`relay_main`);
* :func:`soak` -- hours of a recording's data pushed through ``ordervib run`` faster than real time:
  inputs lost, monitor coverage, the node's memory and latency over the whole push;
* :class:`Runs` / :func:`load_runs` -- every run of a recording's sensor data slot by slot, as
  columns, published over and over in real time re-timed to now (``Runs.timeline``), and
  :func:`bed_inputs` -- one bed's inputs of a node's recording, for an offline replay of that bed.

Publisher and subscriber share this process's monotonic clock.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import orjson

from node.contract import (
    FS,
    MONITOR_SUBSCRIPTION,
    RUN_GAP,
    TopicKind,
    bed_of,
    monitor_key,
    parse_monitor_key,
    parse_sensor_key,
    sensor_key,
    topic_kind,
)
from node.contract.keys import HEALTH_TOPIC

ROOT = Path(__file__).resolve().parents[1]
WARMUP = 40  # slots (1 s) left out of the latency figures
ECHO_PREFIX = "echo/"  # an echo peer replies on echo/<bed>: a key of the harness's own, no node's


@dataclass
class Stream:
    """Slots of one test bed's messages: ``slots[j]`` = [(channel, payload)] in recording order."""

    slots: list[list[tuple[str, bytes]]]
    t0: float  # t of the first message: the node's grid anchor
    last: list[int]  # per slot: index of the last message of a channel the model needs

    def slot_of(self, t: float) -> int:
        return round((t - self.t0) * FS)


def load_stream(path: str, seconds: float, offset: float, needed: set[str], loop: bool = False) -> Stream:
    """``seconds`` of the first run of a recording, starting ``offset`` seconds into it; ``loop``:
    a run shorter than that is repeated (``looped``)."""
    from node.mcap import iter_messages_fast
    n = int(round(seconds * FS))
    last_t: float | None = None
    t0: float | None = None
    cut: float | None = None  # set at the run's first message
    slots: dict[int, list[tuple[str, bytes]]] = {}
    for m in iter_messages_fast(path):
        parsed = parse_sensor_key(m.topic)
        if parsed is None:
            continue
        t = float(orjson.loads(m.payload)["t"])
        if last_t is not None and t - last_t >= RUN_GAP:
            break  # the first run ends
        last_t = t if last_t is None else max(last_t, t)
        if cut is None:
            cut = t + (round(offset * FS) - 0.5) / FS  # between two slots
        if t < cut:
            continue
        if t0 is None:
            t0 = t
        k = round((t - t0) * FS)
        if k >= n + 1:
            break
        slots.setdefault(k, []).append((parsed[1], bytes(m.payload)))
    got = [slots.get(k, []) for k in range(n)]
    if loop and t0 is not None and not got[-1]:
        got = looped(got[:max(k for k in slots if k < n) + 1], n)
    if t0 is None or not got[-1]:
        raise SystemExit(f"{path}: its first run holds less than {offset:g} + {seconds:g} s"
                         + ("" if loop else " (--loop repeats it)"))
    last = [max((i for i, (c, _) in enumerate(s) if c in needed), default=-1) for s in got]
    return Stream(got, t0, last)


def looped(slots: list[list[tuple[str, bytes]]], n: int) -> list[list[tuple[str, bytes]]]:
    """``n`` slots: ``slots`` over and over, each pass's payloads re-timed to follow the last
    without a gap (its ``t`` moved by the passes before, ``len(slots)`` / FS s each): one run of
    sensor time, its data jumping back at each pass's start as at an operating condition's switch.

    >>> s = looped([[("nB", b'{"t":0.0,"v":1.0}')], [("nB", b'{"t":0.025,"v":2.0}')]], 5)
    >>> [(round(d["t"], 6), d["v"]) for d in (orjson.loads(p) for (_, p), in s)]
    [(0.0, 1.0), (0.025, 2.0), (0.05, 1.0), (0.075, 2.0), (0.1, 1.0)]
    """
    out = list(slots[:n])
    period = len(slots)
    docs = [[(channel, orjson.loads(payload)) for channel, payload in slot] for slot in slots]  # once
    while len(out) < n:
        shift = len(out) // period * period / FS
        out += [[(channel, orjson.dumps({**doc, "t": doc["t"] + shift})) for channel, doc in slot]
                for slot in docs[:n - len(out)]]
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_seconds(pid: int) -> float:
    """User + system CPU time so far of a process and its children, those running and those
    ended (the node's transient analyses run in a child process), s (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:  # (a child that ended meanwhile: counted in its parent's, once reaped)
        return 0.0
    total = sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")  # own, and reaped children's
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:  # (ended since)
        return total
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                total += sum(cpu_seconds(int(child)) for child in f.read().split())
        except OSError:
            continue
    return total


class Bench:
    """This process's side: one Zenoh session that publishes the beds and collects replies."""

    def __init__(self, endpoint: str, beds: list[str], channels: list[str], reply_keys: str,
                 on_reply: Callable[[str, bytes, int], None] | None = None) -> None:
        """``on_reply(key, payload, arrival ns)`` instead of keeping every reply in ``arrivals``."""
        import zenoh

        from node.edges.zenoh import json_publisher, open_session, zenoh_config
        self.session = open_session(zenoh_config(None, [endpoint]))
        self.beds = beds
        self.arrivals: list[tuple[str, bytes, int]] = []
        self._handler = on_reply or (lambda *reply: self.arrivals.append(reply))
        self.sub = self.session.declare_subscriber(reply_keys, self._on_reply)
        block = zenoh.CongestionControl.BLOCK
        self.pubs = {(b, c): json_publisher(self.session, sensor_key(b, c), congestion_control=block)
                     for b in beds for c in channels}

    def _on_reply(self, sample) -> None:  # Zenoh thread: stamp and keep only
        self._handler(str(sample.key_expr), sample.payload.to_bytes(), time.monotonic_ns())

    def wait_matched(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        for p in self.pubs.values():
            while not p.matching_status.matching:
                if time.monotonic() > deadline:
                    raise SystemExit("the Zenoh subscriber under test never matched")
                time.sleep(0.02)
        time.sleep(0.5)  # our subscriber's declaration reaches the other side too

    def publish(self, stream: Stream) -> dict:
        """Every slot for every bed at 40 Hz; returns the send times of each sample's last needed channel."""
        nb, ns = len(self.beds), len(stream.slots)
        sent = np.zeros((nb, ns), dtype=np.int64)
        pubs = [{c: p for (b2, c), p in self.pubs.items() if b2 == b} for b in self.beds]
        count, behind = 0, 0.0
        clock = time.monotonic_ns
        start = time.monotonic() + 0.1
        for j, slot in enumerate(stream.slots):
            due = start + j / FS
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                behind = max(behind, -delay)
            last = stream.last[j]
            for bi, bp in enumerate(pubs):
                for i, (c, payload) in enumerate(slot):
                    if i == last:
                        sent[bi, j] = clock()
                    bp[c].put(payload)
                count += len(slot)
        wall = time.monotonic() - start
        return {"sent": sent, "count": count, "wall": wall, "behind_s": behind, "end_ns": clock()}

    def close(self) -> None:
        self.session.close()


def start_node(model: str, record: str, port: int, beds: str | None = None) -> subprocess.Popen:
    """``ordervib run`` listening on ``port``; with ``beds`` (a --beds pattern), connected to a
    router on ``port`` instead."""
    where = ["--listen", f"tcp/127.0.0.1:{port}"] if beds is None else \
        ["--connect", f"tcp/127.0.0.1:{port}", "--beds", beds]
    return subprocess.Popen([sys.executable, "-m", "node.cli", "run", "--model", model, "--record", record,
                             *where, "--quiet"], cwd=ROOT)


def start_router(port: int) -> subprocess.Popen:
    """``ordervib router`` on loopback ``port``."""
    return subprocess.Popen([sys.executable, "-m", "node.cli", "router", "--listen", f"tcp/127.0.0.1:{port}"],
                            cwd=ROOT, stderr=subprocess.DEVNULL)


def start_peer(mode: str, port: int, stream: Stream | None = None, needed: set[str] | None = None):
    """A bare Zenoh subscriber process: ``echo`` replies once per sample, ``count`` only counts."""
    cmd = [sys.executable, "-m", "harness.live", "--peer", mode, "--port", str(port)]
    if mode == "echo":
        if stream is None or needed is None:
            raise ValueError("an echo peer needs the stream and the needed channels")
        cmd += ["--t0", repr(stream.t0), "--needed", ",".join(sorted(needed))]
    p = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if p.stdout is None or p.stdout.readline().strip() != "ready":
        raise SystemExit("the Zenoh peer process did not start")
    return p


def start_relay(port: int, beds: list[str], needed: set[str], target: str) -> subprocess.Popen:
    """The :func:`relay_main` process listening on ``port``, ready."""
    p = subprocess.Popen([sys.executable, "-m", "harness.live", "--peer", "relay", "--port", str(port),
                          "--needed", ",".join(sorted(needed)), "--beds", ",".join(beds), "--target", target],
                         cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if p.stdout is None or p.stdout.readline().strip() != "ready":
        raise SystemExit("the relay process did not start")
    return p


def stop_peer(p: subprocess.Popen) -> dict:
    out, _ = p.communicate("", timeout=30)
    return json.loads(out.strip().splitlines()[-1])


def peer_main(mode: str, port: int, t0: float | None, needed: set[str]) -> int:
    """The bare Zenoh peer: listens, subscribes to every sensor key until stdin closes.

    ``echo``: in the callback, republishes on ``echo/<bed>`` the message that completes
    a sample's needed channels (the node's message pattern without its work: many in,
    one out per sample); ``count``: only counts.
    """
    import zenoh

    from node.contract import SENSOR_SUBSCRIPTION
    from node.edges.zenoh import json_publisher, open_session, zenoh_config
    session = open_session(zenoh_config([f"tcp/127.0.0.1:{port}"], None))
    pubs: dict[str, zenoh.Publisher] = {}
    counts: dict[tuple[str, int], int] = {}
    n = [0]
    block = zenoh.CongestionControl.BLOCK

    def on_sample(sample) -> None:
        n[0] += 1
        payload = sample.payload.to_bytes()
        if mode != "echo":
            return
        bed_ch = parse_sensor_key(str(sample.key_expr))
        if bed_ch is None or bed_ch[1] not in needed:
            return
        bed = bed_ch[0]
        k = (bed, round((orjson.loads(payload)["t"] - t0) * FS))
        c = counts[k] = counts.get(k, 0) + 1
        if c == len(needed):
            del counts[k]
            pub = pubs.get(bed)
            if pub is None:
                pub = pubs[bed] = json_publisher(session, ECHO_PREFIX + bed, congestion_control=block)
            pub.put(payload)

    sub = session.declare_subscriber(SENSOR_SUBSCRIPTION, on_sample)
    print("ready", flush=True)
    sys.stdin.read()
    sub.undeclare()
    print(json.dumps({"received": n[0]}), flush=True)
    session.close()
    return 0


def relay_main(port: int, needed: set[str], beds: set[str], target: str) -> int:
    """A node without its logic: the floor of the node's latency under the same load.

    Listens on ``port`` and takes every sensor key as the node does (a Zenoh ``FifoChannel`` of
    the node's default size, drained by one worker thread in passes of at most ``BATCH_MAX``,
    sleeping ``POLL_S`` when it finds it empty, each message's key, payload and receive stamp
    read as ``LiveNode._pull`` reads them). For each message of one of the ``beds`` on a
    ``needed`` channel it publishes ``{"t": t, "c": channel}`` (``t`` from its payload) on
    ``testbed/<bed>/monitor/<target>`` (``DROP``, as the node): the bench times the reply to
    the channel that completed its sample (a sample may miss a channel, so the relay cannot
    tell which one does); everything else is only taken. Runs until stdin closes, then prints
    ``{"received": N, "published": M}``.
    """
    import threading

    import zenoh

    from node.contract import SENSOR_SUBSCRIPTION
    from node.edges.zenoh import json_publisher, open_session, zenoh_config
    from node.live.node import BATCH_MAX, POLL_S
    session = open_session(zenoh_config([f"tcp/127.0.0.1:{port}"], None))
    sub = session.declare_subscriber(SENSOR_SUBSCRIPTION, zenoh.handlers.FifoChannel(1_000_000))
    drop = zenoh.CongestionControl.DROP
    pubs = {b: json_publisher(session, monitor_key(b, target), congestion_control=drop)
            for b in beds}
    n = [0, 0]
    stop = threading.Event()

    def work() -> None:
        take = sub.try_recv
        while not stop.is_set():
            batch = []
            for _ in range(BATCH_MAX):
                sample = take()
                if sample is None:
                    break
                batch.append((str(sample.key_expr), sample.payload.to_bytes(), sample.timestamp))
            if not batch:
                time.sleep(POLL_S)
                continue
            n[0] += len(batch)
            for key, payload, _ in batch:
                bed_ch = parse_sensor_key(key)
                if bed_ch is None or bed_ch[0] not in beds or bed_ch[1] not in needed:
                    continue
                bed, ch = bed_ch
                pubs[bed].put(orjson.dumps({"t": orjson.loads(payload)["t"], "c": ch}))
                n[1] += 1

    worker = threading.Thread(target=work, daemon=True)
    worker.start()
    print("ready", flush=True)
    sys.stdin.read()
    stop.set()
    worker.join(5)
    sub.undeclare()
    print(json.dumps({"received": n[0], "published": n[1]}), flush=True)
    session.close()
    return 0


def latencies(bench: Bench, stream: Stream, sent: np.ndarray, suffix: str) -> tuple[np.ndarray, dict]:
    """Per sample: arrival of its reply (key ending with ``suffix``) minus its last needed channel's send."""
    bed_index = {b: i for i, b in enumerate(bench.beds)}
    lat: list[float] = []
    seen: dict[str, int] = {}
    for key, payload, arr in list(bench.arrivals):
        if not key.endswith(suffix):
            continue
        bed = bed_of(key) or key.removeprefix(ECHO_PREFIX)  # testbed/<bed>/monitor/<target> or echo/<bed>
        j = stream.slot_of(orjson.loads(payload)["t"])
        bi = bed_index.get(bed)
        if bi is None or not 0 <= j < len(stream.slots):
            continue
        seen[bed] = seen.get(bed, 0) + 1
        if j >= WARMUP and sent[bi, j]:
            lat.append((arr - sent[bi, j]) / 1e6)
    return np.array(lat), seen


def wait_for(cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def stop_node(node: subprocess.Popen) -> None:
    node.send_signal(signal.SIGTERM)
    try:
        node.wait(timeout=60)
    except subprocess.TimeoutExpired:
        node.kill()
        node.wait()


def last_health(bench: Bench) -> dict[str, dict]:
    out = {}
    for key, payload, _ in bench.arrivals:
        bed_name = parse_monitor_key(key)
        if bed_name is not None and bed_name[1] == HEALTH_TOPIC:
            out[bed_name[0]] = orjson.loads(payload)
    return out


def rss_mb(pid: int) -> float:
    """Resident memory of a process, MB (Linux /proc)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


@dataclass
class Soak:
    """What :func:`soak` measured."""

    hours: float  # sensor data pushed, h (gaps between runs not counted)
    wall_s: float  # the push took, s
    sent: int  # sensor messages published
    recorded: int  # of them, in the node's recording
    samples: int  # complete samples published (every channel the model needs)
    monitored: int  # monitor messages received back while publishing
    recorded_monitor: int  # monitor messages in the node's recording (with those its stop flushed)
    lat_ms: np.ndarray  # per monitor message: its arrival minus the publish of the sample's last message
    rss_mb: list[tuple[float, float]]  # (s since the start, node RSS MB), once a second
    health: dict  # the node's last health message
    exit_code: int

    @property
    def lost(self) -> int:
        return self.sent - self.recorded


def soak(model: str, recording: str, hours: float, speed: float, tmp: Path) -> Soak:
    """Push ``hours`` of a recording's sensor data (its runs over and over, each pass shifted in
    time after the last, gaps between runs squeezed out of the pacing) through ``ordervib run``
    at ``speed`` x real time; every reply timed, the node's RSS sampled once a second."""
    from node.mcap import iter_messages_fast
    from node.models.bundle import load_bundle
    from node.runtime.pipeline import MonitorPipeline
    needed = set(MonitorPipeline(load_bundle(model)).sensor_channels)
    msgs = []
    for m in iter_messages_fast(recording):
        parsed = parse_sensor_key(m.topic)
        if parsed is not None:
            msgs.append((m.topic, parsed[1] in needed, orjson.loads(m.payload)))
    msgs.sort(key=lambda x: x[2]["t"])
    times = np.array([d["t"] for _, _, d in msgs])
    steps = np.diff(times, prepend=times[0])
    steps[steps > 1.0] = 0.0  # a gap between runs takes no time
    pace = np.cumsum(steps)  # s of data before each message
    per_pass = float(pace[-1]) + 1 / FS
    span = float(np.ceil(times[-1] - times[0] + 2 * RUN_GAP))  # whole seconds: whole samples
    slots = [round(d["t"] * FS) if need else None for _, need, d in msgs]  # each pass's own, unshifted
    per_pass_samples = len({x for x in slots if x is not None})
    passes = max(1, int(np.ceil(hours * 3600 / per_pass)))
    port = free_port()
    node = start_node(model, str(tmp / "soak.mcap"), port)
    sent_at: dict[int, int] = {}  # sample (round(t * FS)) -> publish of its last needed message
    lat: list[float] = []
    monitored = [0]
    health: dict = {}

    def on_reply(key: str, payload: bytes, arrival: int) -> None:
        d = orjson.loads(payload)
        kind = topic_kind(key)
        if kind is TopicKind.HEALTH:
            health.clear()
            health.update(d)
            return
        if kind is TopicKind.OC:
            return
        monitored[0] += 1
        sent = sent_at.pop(round(d["t"] * FS), None)
        if sent is not None:
            lat.append((arrival - sent) / 1e6)

    bench = Bench(f"tcp/127.0.0.1:{port}", [], [], MONITOR_SUBSCRIPTION, on_reply)
    import zenoh

    from node.edges.zenoh import json_publisher
    pubs = {topic: json_publisher(bench.session, topic, congestion_control=zenoh.CongestionControl.BLOCK)
            for topic in {k for k, _, _ in msgs}}
    rss: list[tuple[float, float]] = []
    sent = 0
    start = time.monotonic()
    try:
        wait_for(lambda: all(p.matching_status.matching for p in pubs.values()), 60)
        time.sleep(0.5)
        start = time.monotonic()
        next_rss = start
        clock = time.monotonic_ns
        for k in range(passes):
            shift = k * span
            slot_shift = k * round(span * FS)
            base = k * per_pass
            for (topic, _, d), slot, due in zip(msgs, slots, pace.tolist(), strict=True):
                now = time.monotonic()
                if now >= next_rss:
                    rss.append((now - start, rss_mb(node.pid)))
                    next_rss += 1.0
                delay = start + (base + due) / speed - now
                if delay > 0.002:
                    time.sleep(delay)
                t = d["t"] + shift
                pubs[topic].put(orjson.dumps({**d, "t": t}))
                sent += 1
                if slot is not None:
                    sent_at[slot + slot_shift] = clock()
        wall = time.monotonic() - start
        samples = passes * per_pass_samples
        wait_for(lambda: monitored[0] >= samples, 30)
        time.sleep(2.2)  # two health periods
        rss.append((time.monotonic() - start, rss_mb(node.pid)))
    finally:
        bench.close()
        stop_node(node)
    from node.mcap import iter_messages
    recorded = recorded_monitor = 0
    for m in iter_messages(tmp / "soak.mcap"):
        kind = topic_kind(m.topic)
        recorded += kind == TopicKind.SENSOR
        recorded_monitor += kind == TopicKind.MONITOR
    return Soak(passes * per_pass / 3600, wall, sent, recorded, samples, monitored[0], recorded_monitor,
                np.array(lat), rss, dict(health), node.returncode)


@dataclass
class Runs:
    """Every run of one bed's sensor data in a recording, slot by slot, as columns.

    Slot s holds the messages ``bounds[s]:bounds[s + 1]`` in recording order: channel
    ``channels[code[i]]``, sensor time ``t[i]``, value ``v[i]`` (NaN: null). Slots are the absolute
    40 Hz grid (``round(t * FS)``), empty ones kept (the pacing); run r is the slots
    ``run_start[r]:run_start[r + 1]``. ``timeline`` publishes them over and over, re-timed.
    """

    channels: list[str]
    code: np.ndarray
    t: np.ndarray
    v: np.ndarray
    bounds: np.ndarray  # (slots + 1,)
    run_start: np.ndarray  # (runs + 1,)

    @property
    def slots(self) -> int:
        return len(self.bounds) - 1

    def save(self, path: str | Path) -> None:
        """As an ``.npz`` file (client processes load it instead of the recording)."""
        np.savez(path, channels=np.array(self.channels), code=self.code, t=self.t, v=self.v,
                 bounds=self.bounds, run_start=self.run_start)

    @classmethod
    def load(cls, path: str | Path) -> Runs:
        with np.load(path) as z:
            return cls([str(c) for c in z["channels"]], z["code"], z["t"], z["v"], z["bounds"],
                       z["run_start"])

    def last_of(self, needed: set[str]) -> np.ndarray:
        """Per slot: the index (into the columns) of its last message of a needed channel, -1 if none."""
        want = np.array([c in needed for c in self.channels])[self.code]
        out = np.full(self.slots, -1, dtype=np.int64)
        idx = np.flatnonzero(want)
        slot = np.searchsorted(self.bounds, idx, side="right") - 1
        out[slot] = idx  # the last of each slot wins (increasing indexes)
        return out

    def payload(self, i: int, shift: float) -> bytes:
        """Message i's payload with its time shifted by ``shift`` s."""
        v = float(self.v[i])
        return orjson.dumps({"t": float(self.t[i]) + shift, "v": None if math.isnan(v) else v})

    def timeline(self, t0: float, pause: float = 1.0) -> Iterator[tuple[float, float, int]]:
        """(wall offset s, sensor shift s, slot) of every slot, the runs over and over, no end.

        The first run's first slot comes at wall offset 0 and sensor time in [t0, t0 + 1); each
        next run ``pause`` s of wall time after the previous one ends and ``RUN_GAP + pause`` s
        later in sensor time (a new run for the node, without the real shutdown's wait). Shifts
        are whole seconds, so each channel's phase within its slot is kept."""
        wall, sensor = 0.0, t0
        while True:
            for a, b in zip(self.run_start[:-1].tolist(), self.run_start[1:].tolist(), strict=True):
                shift = float(math.ceil(sensor - self.t[self.bounds[a]]))
                for s in range(a, b):
                    yield wall + (s - a) / FS, shift, s
                wall += (b - a) / FS + pause
                sensor = float(self.t[self.bounds[a]:self.bounds[b]].max()) + shift + RUN_GAP + pause


def load_runs(path: str, bed: str | None = None) -> Runs:
    """Every run of ``bed``'s sensor data in a recording (default: the first bed seen); runs are
    separated by ``RUN_GAP`` s without data."""
    from node.mcap import iter_messages_fast
    codes: dict[str, int] = {}
    code: list[int] = []
    ts: list[float] = []
    vs: list[float] = []
    for m in iter_messages_fast(path):
        parsed = parse_sensor_key(m.topic)
        if parsed is None or (bed is not None and parsed[0] != bed):
            continue
        bed = parsed[0]
        d = orjson.loads(m.payload)
        code.append(codes.setdefault(parsed[1], len(codes)))
        ts.append(float(d["t"]))
        vs.append(float("nan") if d.get("v") is None else float(d["v"]))
    if not ts:
        raise SystemExit(f"{path}: no sensor message")
    t = np.array(ts)
    newest = np.maximum.accumulate(t)
    cuts = [0, *(np.flatnonzero(t[1:] - newest[:-1] >= RUN_GAP) + 1).tolist(), len(t)]
    order, bounds, run_start = [], [0], [0]
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        k = np.rint(t[a:b] * FS).astype(np.int64)
        k -= k.min()
        o = np.argsort(k, kind="stable") + a  # by slot, recording order within one
        order.append(o)
        counts = np.bincount(k, minlength=int(k.max()) + 1)
        bounds += (bounds[-1] + np.cumsum(counts)).tolist()
        run_start.append(len(bounds) - 1)
    o = np.concatenate(order)
    return Runs(list(codes), np.array(code, dtype=np.int16)[o], t[o], np.array(vs)[o],
                np.array(bounds, dtype=np.int64), np.array(run_start, dtype=np.int64))


def bed_inputs(recording: str | Path, bed: str, out: str | Path) -> int:
    """Copy ``bed``'s sensor inputs of a node's recording (file order, log and publish times kept)
    to ``out``: what an offline replay of that bed alone takes. Returns the messages copied."""
    from node.mcap import RecordingWriter, iter_messages_fast
    n = 0
    with RecordingWriter(str(out)) as w:
        for m in iter_messages_fast(str(recording)):
            bed_ch = parse_sensor_key(m.topic)
            if bed_ch is not None and bed_ch[0] == bed:
                w.write_ns(m.topic, m.log_time, bytes(m.payload), m.publish_time)
                n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    """The peer process of :func:`start_peer`."""
    ap = argparse.ArgumentParser(prog="python -m harness.live")
    ap.add_argument("--peer", choices=["echo", "count", "relay"], required=True)
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--t0", type=float)
    ap.add_argument("--needed", default="")
    ap.add_argument("--beds", default="", help="relay: the beds replied to, comma-separated")
    ap.add_argument("--target", default="", help="relay: the monitor topic's target")
    args = ap.parse_args(argv)
    needed, beds = set(filter(None, args.needed.split(","))), set(filter(None, args.beds.split(",")))
    if args.peer == "relay":  # (no beds: it only takes, the intake's floor)
        return relay_main(args.port, needed, beds, args.target)
    return peer_main(args.peer, args.port, args.t0, needed)


if __name__ == "__main__":
    raise SystemExit(main())
