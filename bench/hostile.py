"""Hostile clients beside a real test bed: the node's latency, memory, accounting and output.

    python -m bench hostile [--minutes 10] [--quiet-minutes 2] [--beds 10000] [--keys 100000]
                            [--burst-x 20] [--siblings 2] [--burst-period 30] [--burst-hold 9.5]
                            [--flood-rate 2000] [--model MODEL] [--workdir DIR] [--floor] [REC.mcap]

One real bed (``tb01``) publishes the recording's sensor stream (its runs over and over, re-timed
to now; a second between runs, a minute in sensor time) at 40 Hz in real time into ``ordervib
run`` on loopback: alone for ``--quiet-minutes`` (the baseline), then for ``--minutes`` beside
outside clients, each a process of its own with its own Zenoh session(s), all with ``BLOCK``
congestion control (a message they count as sent is not dropped on their side):

- siblings: ``--siblings`` beds ``tb02``... publishing the same stream; every ``--burst-period`` s
  each holds its samples for ``--burst-hold`` s (its link down), then sends the backlog at
  ``--burst-x`` times the nominal rate until it has caught up (store and forward);
- clock faults: ``cf-future`` and ``cf-past`` (every 5 s one extra sample stamped a year ahead /
  a day behind), ``cf-jump`` (the whole clock set back an hour at a third of the time, forward
  again at two thirds) and ``cf-dual`` (a second publisher, its own session, on one key, the
  first of the model's channels in the recording, with a clock 2 s ahead); each publishes the
  model's channels. Expected (docs/clock.md): every far sample and every sample of the second
  publisher counted in ``clock_faults`` (or still ``clock_held``), the bed's clock never moved by
  them; cf-jump's two jumps followed (``clock_jumps``; with one more at each new run of the
  stream, a minute of sensor time after a second of wall time, which every bed's clock follows), no fault;
- floods: ``--beds`` distinct bed names (``hb0``..., one sample each in turn) and ``--keys``
  distinct sensor keys, ``--flood-rate`` messages/s each: half of the keys channels on four beds
  (``kf0``..``kf3``, admitted first), a tenth beds with odd but valid names, the rest keys the
  contract's name rule refuses (wildcards, ``$*``, names over 64 characters, a space, non-ASCII,
  a deeper key).

Prints the real bed's latency (publish of a sample's last needed channel -> its monitor message
received) p50 / p99 / max, quiet and hostile (and hostile outside / within the siblings'
bursts), beside the node's own share (from its recording: receipt of the input that completed
the sample -> publish; every latency in ``latency.npz``); the node's and the clients' CPU and the
machine's load; the node's RSS at the start, its largest and at the end; its health counters at the
end; every message sent accounted for (recorded, refused per reason, dropped, and what is left
unexplained); and the real bed's monitor messages in the node's recording against an offline
replay of that bed's inputs alone (``replay.offline``), field by field. PASS/FAIL per criterion:
hostile p99 within ``P99_RATIO`` x quiet; every real sample monitored and none of its inputs
lost; RSS growth over the hostile phase's second half under ``RSS_GROWTH_MB``; every message
accounted for, each refusal reason matching what was sent; each clock fault counted; the beds'
health at most ``HEALTH_MAX_PER_S`` messages within any second of the node's recording (publish
times), printed beside that target; the replay identical; the node's exit 0.

``--floor``: the same run with a node without its logic in the node's place (``harness.live``'s
relay: the node's Zenoh intake, worker passes and monitor topic, nothing else), to show how much
of the real bed's latency, quiet and hostile, the machine and the transport take whatever the node
does; prints the latency table and the ratio only. Without ``--model`` a Lasso bundle is trained on the
committed sample runs first. Recordings and model stay in ``--workdir`` (a new temporary folder
by default).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import orjson

from harness.live import (
    ROOT,
    WARMUP,
    Bench,
    Runs,
    bed_inputs,
    cpu_seconds,
    free_port,
    load_runs,
    rss_mb,
    start_node,
    start_relay,
    stop_node,
    stop_peer,
    wait_for,
)
from node.contract import (
    FS,
    bed_of,
    monitor_key,
    monitor_subscription,
    parse_monitor_key,
    sensor_key,
)
from node.contract.keys import HEALTH_TOPIC
from node.live.health_rate import HEALTH_MAX_PER_S, most_in_a_second

log = logging.getLogger("bench.hostile")

REAL = "tb01"  # the real bed; its siblings are tb02, tb03, ...
CLOCK_BEDS = ("cf-future", "cf-past", "cf-jump", "cf-dual")
KEY_BEDS = 4  # beds kf0.. that carry the key flood's channels
FAULT_EVERY = 200  # slots (5 s) between two far samples of cf-future and cf-past
FUTURE_S = 365 * 86400.0  # a far-future sample: a year ahead
PAST_S = 86400.0  # a far-past sample: a day behind
JUMP_S = 3600.0  # cf-jump's clock is set back this much, then forward again
DUAL_AHEAD_S = 2.0  # cf-dual's second publisher's clock
DUAL_DELAY = 80  # slots (2 s) before the second publisher starts (the bed's own clock first)
BURST_START_S = 5.0  # the siblings' first hold starts this long after the hostile phase
PAUSE_S = 1.0  # wall time between two runs of a bed's stream
P99_RATIO = 2.0  # hostile p99 at most this times the quiet p99
RSS_GROWTH_MB = 50.0  # over the hostile phase's second half
PROGRESS_S = 15.0  # a progress line every so often

# flag: (type, low, high, default, help)
RANGES: dict[str, tuple[type, float, float, float, str]] = {
    "minutes": (float, 0.1, 120, 10, "hostile phase, minutes"),
    "quiet-minutes": (float, 0.1, 60, 2, "quiet baseline before it (the real bed alone), minutes"),
    "beds": (int, 1, 1_000_000, 10_000, "distinct bed names of the bed flood"),
    "keys": (int, 10, 1_000_000, 100_000, "distinct sensor keys of the key flood"),
    "burst-x": (float, 2, 100, 20, "the siblings' burst rate, x the nominal 40 Hz"),
    "siblings": (int, 1, 8, 2, "sibling beds with bursts"),
    "burst-period": (float, 5, 600, 30, "s between two of a sibling's link outages"),
    "burst-hold": (float, 0.5, 300, 9.5, "s each outage lasts (the backlog then goes at --burst-x)"),
    "flood-rate": (float, 10, 50_000, 2000, "messages/s of each flood (bed names, keys)"),
}


class Parser(argparse.ArgumentParser):
    """One line on a bad flag: the program, the flag and what is wrong."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _num(x: float) -> str:
    return f"{x:,.0f}" if float(x).is_integer() else f"{x:g}"


def ranged(kind: type, lo: float, hi: float) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            x = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: "
                                             f"{text!r}") from None
        if not lo <= x <= hi:  # NaN too
            raise argparse.ArgumentTypeError(f"{text} is outside {_num(lo)}..{_num(hi)}")
        return x
    return parse


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = Parser(prog="python -m bench hostile", description=__doc__.split("\n")[0])
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_runs.mcap"))
    ap.add_argument("--model", help="model folder (default: a Lasso bundle trained on the sample runs)")
    ap.add_argument("--workdir", help="folder for the model, recordings and replay (default: a new "
                    "temporary one)")
    for flag, (kind, lo, hi, default, what) in RANGES.items():
        ap.add_argument(f"--{flag}", type=ranged(kind, lo, hi), default=default,
                        help=f"{what} ({_num(lo)}..{_num(hi)}, default {_num(default)})")
    ap.add_argument("--floor", action="store_true", help="a node without its logic in the node's place "
                    "(latency only)")
    args = ap.parse_args(argv)
    if args.burst_hold * args.burst_x / (args.burst_x - 1) >= args.burst_period:
        ap.error(f"--burst-hold {args.burst_hold:g} and its catch-up at --burst-x {args.burst_x:g} do "
                 f"not fit in --burst-period {args.burst_period:g}")
    if not Path(args.recording).is_file():
        ap.error(f"no such recording: {args.recording}")
    if args.model and not (Path(args.model) / "manifest.json").is_file():
        ap.error(f"--model {args.model}: not a model folder (no manifest.json)")
    if args.workdir and Path(args.workdir).exists() and any(Path(args.workdir).iterdir()):
        ap.error(f"--workdir {args.workdir} is not empty")
    return args


# -- what the clients send

def hostile_keys(n: int) -> list[tuple[str, str]]:
    """The key flood: n distinct keys with their category, the first ``KEY_BEDS`` one per kf bed.

    Half "channels" (``testbed/kf<b>/sensor/ch<i>``), a tenth "odd names" (beds whose names keep
    the rule but look odd), the rest "invalid" (keys the rule refuses, each one Zenoh accepts)."""
    n_ch, n_odd = n // 2, n // 10
    channels = [(sensor_key(f"kf{i % KEY_BEDS}", f"ch{i // KEY_BEDS}"), "channels") for i in range(n_ch)]
    odd_forms: list[Callable[[int], str]] = [
        lambda i: f"{i}", lambda i: f"odd.{i}-_", lambda i: f"{i:08d}" + "x" * 56, lambda i: f"_.-{i}",
        lambda i: f"O{i}.v1.2-rc_3"]
    odd = [(sensor_key(odd_forms[i % 5](i), "nB"), "odd names") for i in range(n_odd)]
    bad_forms: list[Callable[[int], str]] = [
        lambda i: f"testbed/*/sensor/w{i}", lambda i: f"testbed/**/sensor/w{i}",
        lambda i: f"testbed/w{i}$*/sensor/nB", lambda i: f"testbed/w{i}/sensor/*",
        lambda i: f"testbed/w{i}/sensor/nB/deeper", lambda i: f"testbed/{'L' * 59}{i:07d}/sensor/nB",
        lambda i: f"testbed/sp ace{i}/sensor/nB", lambda i: f"testbed/\u00e9{i}/sensor/nB",
        lambda i: f"testbed/w{i}/sensor/c$*", lambda i: f"testbed/w{i}/sensor/{'C' * 58}{i:07d}"]
    bad = [(bad_forms[i % len(bad_forms)](i), "invalid") for i in range(n - n_ch - n_odd)]
    head, rest = channels[:KEY_BEDS], [channels[KEY_BEDS:], odd, bad]
    # interleaved, each category spread evenly over the list
    order = sorted(((j / len(part), c, j) for c, part in enumerate(rest) for j in range(len(part))))
    return head + [rest[c][j] for _, c, j in order]


def category(key: str, keyflood: dict[str, str], siblings: set[str]) -> str:
    """The category of a recorded (admitted) sensor key."""
    bed = bed_of(key)
    if bed == REAL:
        return "real bed"
    if bed in siblings:
        return "siblings"
    if bed in CLOCK_BEDS:
        return "clock faults"
    cat = keyflood.get(key)
    if cat is not None:
        return cat
    return "bed names" if bed.startswith("hb") else "other"


# -- the client processes (python -m bench.hostile --client KIND CONFIG)

def _session(endpoint: str):
    from node.edges.zenoh import open_session, zenoh_config
    return open_session(zenoh_config(None, [endpoint]))


def _wait_matched(pub, what: str) -> None:
    if not wait_for(lambda: pub.matching_status.matching, 60):
        raise SystemExit(f"{what}: the node's subscriber never matched")


def _sleep_until(epoch: float) -> None:
    delay = epoch - time.time()
    if delay > 0:
        time.sleep(delay)


class Peak:
    """Messages per second over 0.25 s windows: the largest."""

    def __init__(self) -> None:
        self.start, self.n, self.peak = time.monotonic(), 0, 0.0

    def add(self, n: int) -> None:
        now = time.monotonic()
        if now - self.start >= 0.25:
            self.peak = max(self.peak, self.n / (now - self.start))
            self.start, self.n = now, 0
        self.n += n


def siblings_client(conf: dict) -> tuple[Callable[[float, float], dict], list]:
    import zenoh

    from node.edges.zenoh import json_publisher
    runs = Runs.load(conf["runs"])
    beds = conf["beds"]
    session = _session(conf["endpoint"])
    block = zenoh.CongestionControl.BLOCK
    pubs = [[json_publisher(session, sensor_key(b, c), congestion_control=block) for c in runs.channels]
            for b in beds]
    _wait_matched(pubs[0][0], "siblings")
    x, period, hold = conf["burst_x"], conf["burst_period"], conf["burst_hold"]

    def run(start: float, end: float) -> dict:
        timeline = runs.timeline(start, PAUSE_S)
        due, shift, slot = next(timeline)
        pending: deque[tuple[float, int]] = deque()
        allowance, cap = 0.0, x * FS * 0.05  # slots that may go now; the burst rate over 50 ms at most
        sent, peak, bursts = 0, Peak(), []
        burst_from: float | None = None
        bounds, code = runs.bounds, runs.code.tolist()
        _sleep_until(start)
        last = time.time()
        while (now := time.time()) < end:
            while start + due <= now:
                pending.append((shift, slot))
                due, shift, slot = next(timeline)
            since = now - start - BURST_START_S
            held = since >= 0 and since % period < hold  # the link is down: the samples wait
            if held:
                allowance = 0.0
            else:
                allowance = min(cap, allowance + x * FS * (now - last))
                n = min(len(pending), int(allowance))
                allowance -= n
                if burst_from is None and len(pending) > 2:
                    burst_from = now
                for _ in range(n):
                    sh, s = pending.popleft()
                    for i in range(bounds[s], bounds[s + 1]):
                        data = runs.payload(i, sh)
                        for bp in pubs:
                            bp[code[i]].put(data)
                    k = int(bounds[s + 1] - bounds[s]) * len(pubs)
                    sent += k
                    peak.add(k)
                if burst_from is not None and len(pending) <= 1:
                    bursts.append((burst_from, time.time()))
                    burst_from = None
            last = now
            # a backlog going out: a millisecond; else the next slot due (50 ms at most: the hold's end)
            wait = 0.001 if not held and len(pending) > 1 else min(start + due - time.time(), 0.05)
            time.sleep(max(0.0, min(wait, end - time.time())))
        return {"sent": {"siblings": sent}, "by_bed": dict.fromkeys(beds, sent // len(beds)),
                "peak_rate": peak.peak, "nominal_rate": len(beds) * len(runs.channels) * FS,
                "bursts": bursts, "unsent_slots": len(pending)}
    return run, [session]


def clock_client(conf: dict) -> tuple[Callable[[float, float], dict], list]:
    import zenoh

    from node.edges.zenoh import json_publisher
    runs = Runs.load(conf["runs"])
    channels = [c for c in runs.channels if c in set(conf["channels"])]
    dual_channel = channels[0]
    session, second = _session(conf["endpoint"]), _session(conf["endpoint"])
    block = zenoh.CongestionControl.BLOCK
    pubs = {b: {c: json_publisher(session, sensor_key(b, c), congestion_control=block) for c in channels}
            for b in CLOCK_BEDS}
    dual = json_publisher(second, sensor_key("cf-dual", dual_channel), congestion_control=block)
    _wait_matched(dual, "clock faults (second publisher)")
    _wait_matched(pubs["cf-future"][channels[0]], "clock faults")
    code_of = {runs.channels.index(c): c for c in channels}

    def run(start: float, end: float) -> dict:
        total = int((end - start) * FS)
        jumps_at = (total // 3, 2 * total // 3)
        sent = Counter[str]()
        far = Counter[str]()
        jumps = 0
        run_starts = set(runs.run_start[:-1].tolist())  # the slots that begin a run
        code = runs.code.tolist()
        for j, (wall, shift, s) in enumerate(runs.timeline(start, PAUSE_S)):
            if start + wall >= end:
                break
            _sleep_until(start + wall)
            if j in jumps_at:
                jumps += 1
            if j > 0 and s in run_starts:  # a new run: PAUSE_S of wall time but a minute of sensor
                jumps += 1  # time, a confirmed jump of every bed's clock (cf-future's counts it too)
            back = JUMP_S if jumps_at[0] <= j < jumps_at[1] else 0.0
            first: tuple[float, float] | None = None
            for i in range(runs.bounds[s], runs.bounds[s + 1]):
                c = code_of.get(code[i])
                if c is None:
                    continue
                data = runs.payload(i, shift)
                for b in ("cf-future", "cf-past", "cf-dual"):
                    pubs[b][c].put(data)
                pubs["cf-jump"][c].put(runs.payload(i, shift - back) if back else data)
                sent.update(("cf-future", "cf-past", "cf-dual", "cf-jump"))
                if first is None:
                    first = (float(runs.t[i]) + shift, float(runs.v[i]))
                if c == dual_channel and j >= DUAL_DELAY:
                    dual.put(runs.payload(i, shift + DUAL_AHEAD_S))
                    sent["cf-dual"] += 1
                    far["cf-dual"] += 1
            if first is not None and j % FAULT_EVERY == FAULT_EVERY // 2:
                c = channels[(j // FAULT_EVERY) % len(channels)]
                v = None if math.isnan(first[1]) else first[1]
                pubs["cf-future"][c].put(orjson.dumps({"t": first[0] + FUTURE_S, "v": v}))
                pubs["cf-past"][c].put(orjson.dumps({"t": first[0] - PAST_S, "v": v}))
                sent.update(("cf-future", "cf-past"))
                far.update(("cf-future", "cf-past"))
        return {"sent": {"clock faults": sum(sent.values())}, "by_bed": dict(sent), "far": dict(far),
                "jumps": jumps}
    return run, [session, second]


def flood_client(conf: dict) -> tuple[Callable[[float, float], dict], list]:
    import zenoh

    from node.edges.zenoh import json_publisher
    session = _session(conf["endpoint"])
    probe = json_publisher(session, sensor_key("kf0", "nB"))
    _wait_matched(probe, "floods")
    probe.undeclare()
    beds = [(sensor_key(f"hb{i}", "nB"), "bed names") for i in range(conf["beds"])]
    keys = hostile_keys(conf["keys"])
    rate = conf["rate"]
    put = session.put
    json_enc, block = zenoh.Encoding.APPLICATION_JSON, zenoh.CongestionControl.BLOCK

    def run(start: float, end: float) -> dict:
        sent, rejected = Counter[str](), Counter[str]()
        # the kf beds first (admitted while there is room), then the bed names, then the other keys
        _sleep_until(start + 1.0)
        for key, cat in keys[:KEY_BEDS]:
            put(key, orjson.dumps({"t": time.time(), "v": 1.0}), encoding=json_enc, congestion_control=block)
            sent[cat] += 1
        begin = {"beds": start + 2.0, "keys": start + 3.0}
        lists = {"beds": beds, "keys": keys}
        first = {"beds": 0, "keys": KEY_BEDS}
        done = dict(first)
        while (now := time.time()) < end:
            data = orjson.dumps({"t": now, "v": 1.0})
            for name, items in lists.items():
                if now < begin[name]:
                    continue
                due = first[name] + int((now - begin[name]) * rate)
                while done[name] < due:
                    key, cat = items[done[name] % len(items)]
                    done[name] += 1
                    try:
                        put(key, data, encoding=json_enc, congestion_control=block)
                        sent[cat] += 1
                    except Exception:  # noqa: BLE001 - a key Zenoh itself refuses: never sent
                        rejected[cat] += 1
            time.sleep(0.01)
        return {"sent": dict(sent), "rejected": dict(rejected),
                "distinct": {"bed names": min(done["beds"], len(beds)), "keys": min(done["keys"], len(keys))},
                "rate": {name: (done[name] - first[name]) / max(end - begin[name], 1e-9) for name in lists}}
    return run, [session]


CLIENTS = {"siblings": siblings_client, "clock": clock_client, "flood": flood_client}


def client_main(kind: str, conf: dict) -> int:
    """A client process: set up, say ready, wait for {"start", "end"} on stdin, run, report."""
    run, sessions = CLIENTS[kind](conf)
    print("ready", flush=True)
    go = json.loads(sys.stdin.readline())
    try:
        report = run(go["start"], go["end"])
    finally:
        for s in sessions:
            s.close()
    report["cpu_s"] = time.process_time()
    print(json.dumps(report), flush=True)
    return 0


def start_client(kind: str, conf: dict) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-m", "bench.hostile", "--client", kind, json.dumps(conf)],
                         cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if p.stdout is None or p.stdout.readline().strip() != "ready":
        raise SystemExit(f"the {kind} client process did not start")
    return p


def client_report(kind: str, p: subprocess.Popen) -> dict:
    try:
        out, _ = p.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        p.kill()
        out, _ = p.communicate()
    lines = (out or "").strip().splitlines()
    if p.returncode != 0 or not lines:
        raise SystemExit(f"the {kind} client process failed (exit {p.returncode})")
    return json.loads(lines[-1])


# -- the run

def pct(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) if len(a) else float("nan")


def run(args: argparse.Namespace, tmp: Path) -> dict:
    from node.models.bundle import load_model
    from node.runtime.pipeline import MonitorPipeline
    model = load_model(args.model)
    targets = list(model.targets)[:1] if args.floor else list(model.targets)
    needed = {c for b in model.bundles for c in MonitorPipeline(b).sensor_channels}
    log.info("loading %s", args.recording)
    runs = load_runs(args.recording)
    if needed - set(runs.channels):
        raise SystemExit(f"the model needs {', '.join(sorted(needed - set(runs.channels)))}, which "
                         f"{args.recording} does not hold")
    runs.save(tmp / "runs.npz")
    last = runs.last_of(needed)
    run_of = np.searchsorted(runs.run_start, np.arange(runs.slots), side="right") - 1
    in_run = np.arange(runs.slots) - runs.run_start[run_of]  # slot within its run (the first wait)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    siblings = [f"tb{i:02d}" for i in range(2, args.siblings + 2)]
    node = start_relay(port, [REAL], needed, targets[0]) if args.floor else \
        start_node(args.model, str(tmp / "node.mcap"), port)
    clients: dict[str, subprocess.Popen] = {}
    bench = None
    sent_at: dict[int, tuple[int, str, str]] = {}  # slot on the grid -> (publish ns, phase, last channel)
    lat: list[tuple[str, int, float]] = []  # (phase, publish ns, latency ms)
    counts: Counter[str] = Counter()  # the real bed's monitor messages received, per target
    node_health: dict = {}
    worst_lag = [0.0]
    def on_reply(key: str, payload: bytes, arrival: int) -> None:
        bed_name = parse_monitor_key(key)
        if bed_name is None or bed_name[1] not in targets:
            return
        target = bed_name[1]
        if target != targets[0]:
            counts[target] += 1
            return
        d = orjson.loads(payload)
        slot = round(d["t"] * FS)
        # the relay replies to each needed channel: the sample's last one counts
        if args.floor and (slot not in sent_at or d["c"] != sent_at[slot][2]):
            return
        counts[target] += 1
        got = sent_at.pop(slot, None)
        if got is not None:
            lat.append((got[1], got[0], (arrival - got[0]) / 1e6))

    def on_node_health(sample) -> None:
        d = orjson.loads(sample.payload.to_bytes())
        node_health.clear()
        node_health.update(d)
        worst_lag[0] = max(worst_lag[0], d.get("worker_lag_s") or 0.0)

    rss: list[tuple[float, float]] = []  # (s since the start, node RSS MB), once a second
    cpu: list[tuple[float, float]] = []  # (s since the start, node CPU s so far), with it
    published = real_sent = 0
    late = {"quiet": 0.0, "hostile": 0.0}  # the real bed's publisher: largest delay behind its schedule, s
    try:
        base = {"endpoint": endpoint, "runs": str(tmp / "runs.npz")}
        log.info("node on %s; starting the client processes", endpoint)
        clients["siblings"] = start_client("siblings", {**base, "beds": siblings, "burst_x": args.burst_x,
                                                        "burst_period": args.burst_period,
                                                        "burst_hold": args.burst_hold})
        clients["clock"] = start_client("clock", {**base, "channels": sorted(needed)})
        clients["flood"] = start_client("flood", {**base, "beds": args.beds, "keys": args.keys,
                                                  "rate": args.flood_rate})
        bench = Bench(endpoint, [REAL], runs.channels, monitor_subscription(REAL), on_reply)
        sub = bench.session.declare_subscriber("ordervib/node/*/health", on_node_health)
        bench.wait_matched()
        pubs = [bench.pubs[(REAL, c)] for c in runs.channels]
        quiet_s, hostile_s = args.quiet_minutes * 60, args.minutes * 60
        start = time.time() + 1.0
        hostile, end = start + quiet_s, start + quiet_s + hostile_s
        for p in clients.values():
            assert p.stdin is not None
            p.stdin.write(json.dumps({"start": hostile, "end": end}) + "\n")
            p.stdin.flush()
        mono0 = time.monotonic() + (start - time.time())
        mono_hostile, mono_end = mono0 + quiet_s, mono0 + quiet_s + hostile_s
        log.info("quiet baseline %.0f s, then hostile %.0f s (%s)", quiet_s, hostile_s,
                 time.strftime("%H:%M:%S", time.localtime(end)) + " end")
        next_rss = next_log = mono0
        bounds, code, times = runs.bounds, runs.code.tolist(), runs.t
        clock = time.monotonic_ns
        for wall, shift, s in runs.timeline(start, PAUSE_S):
            due = mono0 + wall
            if due >= mono_end:
                break
            while (now := time.monotonic()) < due or now >= next_rss:
                if now >= next_rss:
                    rss.append((now - mono0, rss_mb(node.pid)))
                    cpu.append((now - mono0, cpu_seconds(node.pid)))
                    next_rss += 1.0
                if now >= next_log:
                    next_log += PROGRESS_S
                    progress(now - mono0, quiet_s, hostile_s, lat, node_health, rss)
                if node.poll() is not None:
                    raise SystemExit(f"the node exited ({node.returncode}) {now - mono0:.0f} s into the run")
                if now < due:
                    time.sleep(min(due - now, 0.05))
            phase = "warmup" if in_run[s] < WARMUP else "quiet" if due < mono_hostile else "hostile"
            key = "quiet" if due < mono_hostile else "hostile"
            late[key] = max(late[key], time.monotonic() - due)
            li = last[s]
            for i in range(bounds[s], bounds[s + 1]):
                pubs[code[i]].put(runs.payload(i, shift))
                if i == li:
                    sent_at[round((float(times[i]) + shift) * FS)] = (clock(), phase, runs.channels[code[i]])
            real_sent += int(bounds[s + 1] - bounds[s])
            published += li >= 0
        log.info("publishing done: %d real-bed messages, %d samples; waiting for the clients", real_sent,
                 published)
        wait_for(lambda: min((counts[x] for x in targets), default=0) >= published, 15)
        reports = {kind: client_report(kind, p) for kind, p in clients.items()}
        time.sleep(2.5)  # two health periods: the node's last counters
        rss.append((time.monotonic() - mono0, rss_mb(node.pid)))
        load = os.getloadavg()[1]  # the machine's, over the last 5 minutes
        sub.undeclare()
    finally:
        if bench is not None:
            bench.close()
        for p in clients.values():
            if p.poll() is None:
                p.kill()
        if args.floor:
            stop_peer(node)
        else:
            stop_node(node)
    log.info("node stopped (exit %s); reading its recording", node.returncode)
    return {"targets": targets, "siblings": siblings, "lat": lat, "counts": dict(counts), "rss": rss,
            "cpu": cpu, "load": load, "late": late, "published": published, "real_sent": real_sent,
            "unanswered": len(sent_at), "reports": reports, "exit": node.returncode,
            "live_health": dict(node_health), "worst_lag": worst_lag[0], "quiet_s": quiet_s,
            "hostile_s": hostile_s, "mono0": mono0, "start": start, "hostile": hostile, "tmp": tmp}


def progress(at: float, quiet_s: float, hostile_s: float, lat: list, health: dict, rss: list) -> None:
    phase = "quiet" if at < quiet_s else "hostile"
    recent = np.array([x for p, _, x in lat[-2000:] if p == phase])
    refused = {k: v for k, v in (health.get("refused") or {}).items() if v}
    log.info("%s %.0f/%.0f s: real-bed latency p99 %.1f ms (last %d); node received %s, refused %s, "
             "dropped %s, tracked %s, worker lag %s s, %s us/message; RSS %.0f MB", phase,
             at if phase == "quiet" else at - quiet_s, quiet_s if phase == "quiet" else hostile_s,
             pct(recent, 99), len(recent), health.get("received"), refused or "none", health.get("dropped"),
             health.get("tracked"), health.get("worker_lag_s"), health.get("cpu_us_per_message"),
             rss[-1][1] if rss else float("nan"))


# -- the node's recording and the offline replay

def read_recording(path: Path, keyflood: dict[str, str], siblings: set[str], watch: set[str],
                   target: str) -> dict:
    """Sensor inputs recorded per category, the last health of the ``watch`` beds and the node's
    own, the real bed's outputs (every topic but health) in order, and the node's own share of
    each ``target`` message's latency: its publish minus the receipt of the real bed's input
    recorded just before it (the one that completed it), (publish ns, ms) each."""
    from node.contract import TopicKind, topic_kind
    from node.mcap import iter_messages_fast
    recorded: Counter[str] = Counter()
    per_topic: Counter[str] = Counter()
    health: dict[str, dict] = {}
    node_health: dict = {}
    outputs: dict[str, list[bytes]] = {}
    timed = monitor_key(REAL, target)
    internal: list[tuple[int, float]] = []
    health_ns: list[int] = []  # every bed health's publish time
    received = 0
    kinds: dict[str, tuple[TopicKind, str | None]] = {}  # topic -> its kind and bed
    for m in iter_messages_fast(str(path)):
        topic = m.topic
        known = kinds.get(topic)
        if known is None:
            known = kinds[topic] = (topic_kind(topic), bed_of(topic))
        kind, bed = known
        if kind == TopicKind.SENSOR:
            per_topic[topic] += 1
            if bed == REAL:
                received = m.publish_time
        elif kind == TopicKind.HEALTH:
            health_ns.append(m.publish_time)
            if bed in watch:
                health[bed] = orjson.loads(m.payload)
        elif kind == TopicKind.NODE_HEALTH:
            node_health = orjson.loads(m.payload)
        elif bed == REAL and kind != TopicKind.OTHER:
            outputs.setdefault(topic, []).append(bytes(m.payload))
            if topic == timed:
                internal.append((m.publish_time, (m.publish_time - received) / 1e6))
    for topic, n in per_topic.items():
        recorded[category(topic, keyflood, siblings)] += n
    return {"recorded": recorded, "health": health, "node_health": node_health, "outputs": outputs,
            "topics": len(kinds), "internal": internal, "health_rate": health_rate(health_ns)}


def health_rate(times_ns: list[int]) -> dict:
    """The beds' health messages a second: the most within any one second [t, t + 1 s) of their
    publish times, and the mean over their span."""
    span = (max(times_ns) - min(times_ns)) / 1e9 if len(times_ns) > 1 else 0.0
    return {"max": most_in_a_second(times_ns), "mean": len(times_ns) / span if span else float("nan"),
            "count": len(times_ns)}


def real_outputs(path: Path) -> dict[str, list[bytes]]:
    from node.mcap import iter_messages_fast
    out: dict[str, list[bytes]] = {}
    for m in iter_messages_fast(str(path)):
        bed_name = parse_monitor_key(m.topic)
        if bed_name is not None and bed_name[0] == REAL and bed_name[1] != HEALTH_TOPIC:
            out.setdefault(m.topic, []).append(bytes(m.payload))
    return out


def compare(live: dict[str, list[bytes]], offline: dict[str, list[bytes]]) -> dict:
    """Message by message per topic: identical bytes, or the fields that differ."""
    n = differ = same_fields = 0
    first: str | None = None
    lengths = {}
    for topic in sorted(set(live) | set(offline)):
        a, b = live.get(topic, []), offline.get(topic, [])
        if len(a) != len(b):
            lengths[topic] = (len(a), len(b))
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            n += 1
            if x == y:
                continue
            dx, dy = orjson.loads(x), orjson.loads(y)
            fields = [k for k in dict.fromkeys([*dx, *dy]) if dx.get(k, "<absent>") != dy.get(k, "<absent>")]
            if not fields:
                same_fields += 1
                continue
            differ += 1
            if first is None:
                shown = "; ".join(f"{k}: live {dx.get(k, '<absent>')!r}, replay {dy.get(k, '<absent>')!r}"
                                  for k in fields[:4])
                first = f"{topic} #{i} (t {dx.get('t')}): {shown}"
    return {"compared": n, "differ": differ, "same_fields": same_fields, "first": first, "lengths": lengths}


# -- the report

PHASE_ROWS = {"quiet": "quiet (alone)", "hostile": "hostile", "calm": "hostile, outside the siblings' bursts",
              "burst": "hostile, within a burst (+1 s)"}


def latency_phases(r: dict) -> dict[str, np.ndarray]:
    """The real bed's latencies (ms): "quiet", "hostile", hostile outside the siblings' bursts
    ("calm") and within one (+1 s for the backlog, "burst")."""
    lat = r["lat"]
    mono_of = r["mono0"] - r["start"]  # epoch -> monotonic
    windows = [(a + mono_of, b + mono_of + 1.0) for a, b in r["reports"]["siblings"]["bursts"]]

    def in_burst(ns: int) -> bool:
        x = ns / 1e9
        return any(a <= x <= b for a, b in windows)
    return {"quiet": np.array([x for p, _, x in lat if p == "quiet"]),
            "hostile": np.array([x for p, _, x in lat if p == "hostile"]),
            "calm": np.array([x for p, ns, x in lat if p == "hostile" and not in_burst(ns)]),
            "burst": np.array([x for p, ns, x in lat if p == "hostile" and in_burst(ns)])}


def latency_row(name: str, a: np.ndarray) -> list[str]:
    """A latency table's row: name, samples, p50 / p99 / max ms."""
    return [name, f"{len(a):,}", f"{pct(a, 50):.2f}", f"{pct(a, 99):.2f}", f"{pct(a, 100):.2f}"]


def cpu_figures(r: dict) -> str:
    """The process under test's CPU quiet / hostile (of a core), the clients' while hostile, and
    the machine's load."""
    cpu, quiet_s = r["cpu"], r["quiet_s"]
    at = next(((s, c) for s, c in cpu if s >= quiet_s), cpu[-1])

    def share(a: tuple[float, float], b: tuple[float, float]) -> str:
        return f"{(b[1] - a[1]) / max(b[0] - a[0], 1e-9) * 100:.0f} %"
    clients = sum(rep.get("cpu_s", 0.0) for rep in r["reports"].values()) / r["hostile_s"]
    return (f"{share(cpu[0], at)} / {share(at, cpu[-1])}; {clients * 100:.0f} %; {r['load']:.1f} on "
            f"{os.cpu_count()} cores")


def report_floor(args: argparse.Namespace, r: dict) -> None:
    """``--floor``: the relay's latency table, its ratio and the machine's figures."""
    from node.console.table import print_table
    phases = latency_phases(r)
    quiet, hostile = phases["quiet"], phases["hostile"]
    rows = [latency_row(name, phases[k]) for k, name in PHASE_ROWS.items()]
    print_table(["real bed tb01, relay (no node logic)", "samples", "p50 ms", "p99 ms", "max ms"], rows,
                markdown=True, title="Floor: last needed channel published -> the relay's reply received "
                                     f"(each run's first {WARMUP} samples left out)")
    print_table(["figure", "measured"], [
        ["hostile p99 / quiet p99", f"{pct(hostile, 99) / pct(quiet, 99):.2f} x (the node's criterion: "
         f"<= {P99_RATIO:g} x)"],
        ["replies / real samples published", f"{r['counts'].get(r['targets'][0], 0):,} / {r['published']:,}"],
        ["relay CPU, quiet / hostile (of a core); the clients', hostile; machine load (5 min)",
         cpu_figures(r)],
        ["real bed's publisher: largest delay behind its schedule, quiet / hostile",
         f"{r['late']['quiet'] * 1e3:.1f} / {r['late']['hostile'] * 1e3:.1f} ms"],
    ], markdown=True, title=f"Floor under the hostile clients ({args.minutes:g} min after "
                            f"{args.quiet_minutes:g} min quiet)")


def report(args: argparse.Namespace, r: dict, rec: dict, cmp: dict, replayed: int, real_inputs: int) -> bool:
    from node.console.table import print_table
    checks: dict[str, bool] = {}

    def res(k: str) -> str:
        return "PASS" if checks[k] else "FAIL"

    # latency
    lat = r["lat"]
    phases = latency_phases(r)
    quiet, hostile = phases["quiet"], phases["hostile"]
    checks["latency"] = bool(len(quiet) and len(hostile)) and pct(hostile, 99) <= P99_RATIO * pct(quiet, 99)

    hostile_ns = r["hostile"] * 1e9
    own = [(ns, x) for ns, x in rec["internal"] if ns >= r["start"] * 1e9 + WARMUP / FS * 1e9]
    own_quiet = np.array([x for ns, x in own if ns < hostile_ns])
    own_hostile = np.array([x for ns, x in own if ns >= hostile_ns])
    worst: list[tuple[float, int]] = []  # the three largest, a second apart at least (three stalls)
    for x, ns in sorted(((x, ns) for ns, x in own if ns >= hostile_ns), reverse=True):
        if len(worst) == 3:
            break
        if all(abs(ns - other) > 1e9 for _, other in worst):
            worst.append((x, ns))
    np.savez(r["tmp"] / "latency.npz", phase=np.array([p for p, _, _ in lat]),
             publish_s=np.array([ns / 1e9 - r["mono0"] for _, ns, _ in lat]),
             ms=np.array([x for _, _, x in lat]), own_s=np.array([ns / 1e9 - r["start"] for ns, _ in own]),
             own_ms=np.array([x for _, x in own]))
    print_table(["real bed tb01", "samples", "p50 ms", "p99 ms", "max ms"],
                [*(latency_row(name, phases[k]) for k, name in PHASE_ROWS.items()),
                 latency_row("node's own share, quiet (its recording: receipt -> publish)", own_quiet),
                 latency_row("node's own share, hostile", own_hostile)], markdown=True,
                title="Latency: last needed channel published -> monitor message received "
                      f"(each run's first {WARMUP} samples left out)")

    # memory
    rss = r["rss"]
    quiet_s, hostile_s = r["quiet_s"], r["hostile_s"]
    second_half = [m for s, m in rss if s >= quiet_s + hostile_s / 2] or [rss[-1][1]]
    at_hostile = next((m for s, m in rss if s >= quiet_s), rss[-1][1])
    growth = second_half[-1] - second_half[0]
    checks["rss"] = growth < RSS_GROWTH_MB

    # the node's counters
    nh = rec["node_health"]
    refused = nh.get("refused", {})
    health = rec["health"]
    real_h = health.get(REAL, {})

    # accounting
    reports = r["reports"]
    sent: Counter[str] = Counter({"real bed": r["real_sent"]})
    rejected: Counter[str] = Counter()
    for rep in reports.values():
        sent.update(rep["sent"])
        rejected.update(rep.get("rejected", {}))
    recorded = rec["recorded"]
    total_sent = sum(sent.values())
    received, dropped = nh.get("received", 0), nh.get("dropped", 0)
    uncounted = total_sent - received - dropped
    ref_in = sum(refused.get(k, 0) for k in ("key", "not_admitted", "bed_limit", "channel_limit"))
    unexplained = received - sum(recorded.values()) - ref_in
    checks["accounted"] = uncounted == 0 and unexplained == 0 and refused.get("recording_channels", 0) == 0
    admitted_cats = ("real bed", "siblings", "clock faults")
    limit_cats = ("bed names", "channels", "odd names")
    limits = sum(refused.get(k, 0) for k in ("bed_limit", "channel_limit", "not_admitted"))
    checks["reasons"] = (refused.get("key", 0) == sent["invalid"] - recorded["invalid"]
                         and limits == sum(sent[c] - recorded[c] for c in limit_cats)
                         and all(sent[c] == recorded[c] for c in admitted_cats) and recorded["other"] == 0)
    checks["real inputs"] = (sent["real bed"] == recorded["real bed"] == real_inputs
                             and real_h.get("dropped") == 0)
    # each sample with a needed channel answered (more: a slot of the cadence with none, emitted as missing)
    checks["monitored"] = r["unanswered"] == 0 and all(r["counts"].get(t, 0) >= r["published"]
                                                       for t in r["targets"])

    # clock faults
    clock_rep = reports["clock"]
    far = clock_rep["far"]
    rows_clock = []
    ok_clock = True
    for bed in CLOCK_BEDS:
        h = health.get(bed, {})
        faults, held = h.get("clock_faults", 0), h.get("clock_held", 0)
        if bed == "cf-jump":
            expect, ok = f"{clock_rep['jumps']} jumps, 0 faults", (h.get("clock_jumps") == clock_rep["jumps"]
                                                                    and faults == 0)
        else:
            n = far.get(bed, 0)
            ok = faults + held == n
            expect = f"faults + held = {n:,}"
            if not ok:
                expect += f" ({n - faults - held:,} taken as the bed's clock)"
        ok_clock &= ok
        rows_clock.append([bed, f"{clock_rep['by_bed'].get(bed, 0):,}", f"{far.get(bed, 0):,}",
                           f"{faults:,}", f"{h.get('clock_conflicts', 0):,}", f"{h.get('clock_jumps', 0)}",
                           f"{held}", expect, "PASS" if ok else "FAIL"])
    checks["clock"] = ok_clock

    checks["replay"] = (cmp["differ"] == 0 and cmp["same_fields"] == 0 and not cmp["lengths"]
                        and cmp["compared"] > 0)
    checks["exit"] = r["exit"] == 0 and bool(nh.get("recording", False))
    rate = rec["health_rate"]
    checks["health rate"] = rate["max"] <= HEALTH_MAX_PER_S

    flood = reports["flood"]
    sib = reports["siblings"]
    print_table(["figure", "measured"], [
        ["node CPU, quiet / hostile (of a core); the clients' processes, hostile; machine load (5 min)",
         cpu_figures(r)],
        ["real bed's publisher: largest delay behind its 40 Hz schedule, quiet / hostile",
         f"{r['late']['quiet'] * 1e3:.1f} / {r['late']['hostile'] * 1e3:.1f} ms"],
        ["node RSS at the start (quiet) / hostile start / largest / end",
         f"{rss[0][1]:.0f} / {at_hostile:.0f} / {max(m for _, m in rss):.0f} / {rss[-1][1]:.0f} MB"],
        ["RSS growth over the hostile phase / its second half",
         f"{rss[-1][1] - at_hostile:+.1f} / {growth:+.1f} MB (target < {RSS_GROWTH_MB:g} MB: {res('rss')})"],
        ["node health at the end: received / dropped", f"{received:,} / {dropped:,}"],
        ["refused per reason", ", ".join(f"{k} {v:,}" for k, v in refused.items())],
        ["beds tracked / bound; expired; silent (out of the health rotation)",
         f"{nh.get('tracked')} / {nh.get('max_beds')}; {nh.get('expired')}; {nh.get('silent')}"],
        ["beds' health: most within a second / mean; each bed's every", f"{rate['max']} / "
         f"{rate['mean']:.1f} messages/s (target <= {HEALTH_MAX_PER_S}); {nh.get('health_every_s')} s"],
        ["recording / unrecorded; MCAP topics",
         f"{nh.get('recording')} / {nh.get('unrecorded')}; {rec['topics']:,}"],
        ["worker: CPU per message (last) / largest queue lag seen", f"{nh.get('cpu_us_per_message')} us / "
         f"{r['worst_lag']:.3f} s"],
        ["the node's own largest latencies of the real bed (hostile)",
         ", ".join(f"{x:.0f} ms at +{ns / 1e9 - r['hostile']:.1f} s" for x, ns in worst) or "none"],
        ["real bed health: received / dropped / missing / late / duplicates",
         f"{real_h.get('received', 0):,} / {real_h.get('dropped')} / "
         f"{sum(real_h.get('missing', {}).values())} / {real_h.get('late')} / {real_h.get('duplicates')}"],
        ["siblings: nominal / peak rate (0.25 s windows); bursts",
         f"{sib['nominal_rate']:,.0f} / {sib['peak_rate']:,.0f} messages/s "
         f"({sib['peak_rate'] / sib['nominal_rate']:.1f} x); {len(sib['bursts'])}"],
        ["floods: distinct bed names / keys sent; rate achieved",
         f"{flood['distinct']['bed names']:,} / {flood['distinct']['keys']:,}; "
         + ", ".join(f"{k} {v:,.0f}/s" for k, v in flood["rate"].items())],
    ], markdown=True, title="The node under the hostile clients")

    print_table(["bed", "sent", "far / second clock", "clock_faults", "conflicts", "jumps", "held",
                 "expected", "result"], rows_clock, markdown=True,
                title="Clock faults (each bed's last health)")

    reasons = {"real bed": "-", "siblings": "-", "clock faults": "- (clock_faults)", "bed names": "bed_limit",
               "channels": "channel_limit", "odd names": "bed_limit", "invalid": "key"}
    rows = [[c, f"{sent[c]:,}", f"{recorded[c]:,}", f"{sent[c] - recorded[c]:,}", reasons[c],
             f"{rejected[c]:,}"] for c in reasons]
    kept = sum(recorded.values())
    rows.append(["all", f"{total_sent:,}", f"{kept:,}", f"{total_sent - kept:,}", f"refused {ref_in:,}",
                 f"{sum(rejected.values()):,}"])
    print_table(["client messages", "sent", "recorded (admitted)", "not recorded", "refused as",
                 "rejected by Zenoh (not sent)"], rows, markdown=True, title="Every message accounted for")
    print_table(["figure", "measured", "target", "result"], [
        ["sent - node received - dropped (lost uncounted)", f"{uncounted:,}", "0", ""],
        ["received - recorded - refused (unexplained)", f"{unexplained:,}", "0", res("accounted")],
        ["refused key / invalid keys sent", f"{refused.get('key', 0):,} / {sent['invalid']:,}", "equal", ""],
        ["refused bed_limit + channel_limit + not_admitted / bed names, channels and odd names not recorded",
         f"{limits:,} / {sum(sent[c] - recorded[c] for c in limit_cats):,}", "equal", res("reasons")],
    ], markdown=True)

    first = cmp["first"] or "none"
    print_table(["figure", "measured"], [
        ["real bed inputs in the node's recording -> replayed", f"{real_inputs:,} -> {replayed:,} outputs"],
        ["monitor messages compared (every topic but health)", f"{cmp['compared']:,}"],
        ["differing / same fields, other bytes", f"{cmp['differ']:,} / {cmp['same_fields']:,}"],
        ["topics whose counts differ (live, replay)", str(cmp["lengths"] or "none")],
        ["first difference", first],
    ], markdown=True, title="The real bed's output live against an offline replay of its own inputs")

    crit = [
        ["latency", f"hostile p99 {pct(hostile, 99):.2f} ms vs quiet p99 {pct(quiet, 99):.2f} ms "
         f"({pct(hostile, 99) / pct(quiet, 99):.2f} x)", f"<= {P99_RATIO:g} x", res("latency")],
        ["real bed monitored", ", ".join(f"{t} {r['counts'].get(t, 0):,}" for t in r["targets"])
         + f" of {r['published']:,} samples; unanswered {r['unanswered']:,}", "all", res("monitored")],
        ["real bed inputs", f"sent {sent['real bed']:,}, recorded {recorded['real bed']:,}, dropped "
         f"{real_h.get('dropped')}", "none lost", res("real inputs")],
        ["memory", f"RSS {rss[0][1]:.0f} -> {rss[-1][1]:.0f} MB (max {max(m for _, m in rss):.0f}); "
         f"second half {growth:+.1f} MB", f"< {RSS_GROWTH_MB:g} MB", res("rss")],
        ["every message accounted for", f"uncounted {uncounted:,}, unexplained {unexplained:,}", "0, 0",
         res("accounted")],
        ["refusals by reason", "key, limits as sent" if checks["reasons"] else "mismatch (tables above)",
         "match", res("reasons")],
        ["clock faults counted", "each clock bed as expected" if checks["clock"]
         else "mismatch (table above)", "match", res("clock")],
        ["live = offline replay", f"{cmp['differ']:,} of {cmp['compared']:,} differ", "identical",
         res("replay")],
        ["beds' health rate", f"at most {rate['max']} a second ({rate['count']:,} messages, mean "
         f"{rate['mean']:.1f}/s)", f"<= {HEALTH_MAX_PER_S}/s", res("health rate")],
        ["node exit / recording", f"{r['exit']} / {nh.get('recording')}", "0 / true", res("exit")],
    ]
    print_table(["criterion", "measured", "target", "result"], crit, markdown=True,
                title=f"Hostile soak: {args.minutes:g} min hostile after {args.quiet_minutes:g} min quiet, "
                      f"{args.beds:,} bed names, {args.keys:,} keys, bursts x{args.burst_x:g}")
    return all(checks.values())


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--client"]:
        return client_main(argv[1], json.loads(argv[2]))
    args = parse_args(argv)
    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                            format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    from harness import make
    tmp = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="ordervib-hostile-"))
    tmp.mkdir(parents=True, exist_ok=True)
    log.info("work folder %s", tmp)
    if not args.model:
        log.info("training a Lasso model on the sample runs")
        args.model = make.sample_model(tmp / "model")
    r = run(args, tmp)
    if args.floor:
        report_floor(args, r)
        return 0
    keyflood = {k: c for k, c in hostile_keys(args.keys) if c != "invalid"}
    rec = read_recording(tmp / "node.mcap", keyflood, set(r["siblings"]), {REAL, *CLOCK_BEDS, *r["siblings"]},
                         r["targets"][0])
    real_inputs = bed_inputs(tmp / "node.mcap", REAL, tmp / "real-inputs.mcap")
    log.info("replaying the real bed's %d inputs offline", real_inputs)
    rep = make.replay(tmp / "real-inputs.mcap", args.model, str(tmp / "replay.mcap"))
    cmp = compare(rec["outputs"], real_outputs(tmp / "replay.mcap"))
    ok = report(args, r, rec, cmp, rep.published, real_inputs)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
