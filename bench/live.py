"""The live node over Zenoh on loopback, each figure beside its ceiling measured in the same run.

    python -m bench live [--seconds 60] [--beds 20] [--ceiling-seconds 15] [--model MODEL] [REC.mcap]

1. Latency, one test bed: the recording's channels published at 40 Hz in real time
   (a sample's messages back to back at its due time) into ``ordervib run``;
   latency = arrival of the monitor message of a sample minus the publish of the
   last channel of that sample the model needs (publisher and subscriber share
   this process's clock). Ceiling: the same stream through a bare Zenoh echo
   process (its callback republishes each message), the round trip of the same
   message.
2. Throughput: ``--beds`` test beds (bed01, bed02, ...) each publishing every
   channel at 40 Hz in real time into one node process. PASS when the node
   receives every message, its queue never overflows, every sample of every bed
   is complete (nothing missing from the cadence, nothing late) and has its
   monitor message. Ceiling: a bare Zenoh subscriber process counting the same
   stream.

Without ``--model`` a Lasso bundle is trained on the committed sample runs
first. The stream is the first run of the recording from ``--offset`` seconds
(30 s: the window covers the first operating conditions, so the models run).
"""


from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np
import orjson

from harness.live import (
    ROOT,
    WARMUP,
    Bench,
    Stream,
    cpu_seconds,
    free_port,
    last_health,
    latencies,
    load_stream,
    start_node,
    start_peer,
    stop_node,
    stop_peer,
    wait_for,
)
from node.contract import FS, MONITOR_SUBSCRIPTION

LATENCY_P99_MS = 20.0


def pct(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) if len(a) else float("nan")


def run_latency(args, stream: Stream, channels: list[str], needed: set[str], target: str,
                tmp: Path) -> dict:
    beds = ["lat01"]
    # ceiling: Zenoh alone, a bare echo process
    port = free_port()
    peer = start_peer("echo", port, stream, needed)
    b = Bench(f"tcp/127.0.0.1:{port}", beds, channels, "echo/*")
    try:
        b.wait_matched()
        short = Stream(stream.slots[:int(args.ceiling_seconds * FS)], stream.t0, stream.last)
        r = b.publish(short)
        wait_for(lambda: len(b.arrivals) >= len(short.slots), 10)
        zlat, zseen = latencies(b, short, r["sent"], "echo/lat01")
    finally:
        b.close()
        stop_peer(peer)
    # the node
    port = free_port()
    node = start_node(args.model, str(tmp / "latency.mcap"), port)
    b = Bench(f"tcp/127.0.0.1:{port}", beds, channels, MONITOR_SUBSCRIPTION)
    try:
        b.wait_matched()
        r = b.publish(stream)
        suffix = f"/monitor/{target}"
        wait_for(lambda: sum(k.endswith(suffix) for k, _, _ in b.arrivals) >= len(stream.slots), 10)
        nlat, seen = latencies(b, stream, r["sent"], suffix)
    finally:
        b.close()
        stop_node(node)
    return {"zenoh": zlat, "node": nlat, "monitor": seen.get("lat01", 0), "slots": len(stream.slots),
            "behind_s": r["behind_s"], "zenoh_replies": zseen.get("lat01", 0),
            "zenoh_slots": len(short.slots)}


def run_throughput(args, stream: Stream, channels: list[str], target: str, tmp: Path) -> dict:
    beds = [f"bed{i:02d}" for i in range(1, args.beds + 1)]
    # ceiling: a bare Zenoh subscriber that only counts
    port = free_port()
    peer = start_peer("count", port)
    b = Bench(f"tcp/127.0.0.1:{port}", beds, channels, "nothing/**")
    try:
        b.wait_matched()
        short = Stream(stream.slots[:int(args.ceiling_seconds * FS)], stream.t0, stream.last)
        cpu0 = cpu_seconds(peer.pid)
        rz = b.publish(short)
        time.sleep(0.5)
        zcpu = (cpu_seconds(peer.pid) - cpu0) / rz["wall"]
    finally:
        b.close()
        zrecv = stop_peer(peer)["received"]
    # the node
    port = free_port()
    node = start_node(args.model, str(tmp / "throughput.mcap"), port)
    b = Bench(f"tcp/127.0.0.1:{port}", beds, channels, MONITOR_SUBSCRIPTION)
    suffix = f"/monitor/{target}"
    try:
        b.wait_matched()
        cpu0 = cpu_seconds(node.pid)
        r = b.publish(stream)
        cpu = (cpu_seconds(node.pid) - cpu0) / r["wall"]
        expected = len(stream.slots) * len(beds)
        wait_for(lambda: sum(k.endswith(suffix) for k, _, _ in b.arrivals) >= expected, 30)
        drained = max((a for k, _, a in b.arrivals if k.endswith(suffix)), default=r["end_ns"])
        drain_ms = max(0.0, (drained - r["end_ns"]) / 1e6)
        time.sleep(2.2)  # two health periods after the backlog
        lat, seen = latencies(b, stream, r["sent"], suffix)
        health = last_health(b)
        reports = [orjson.loads(p) for k, p, _ in b.arrivals if k.endswith("/monitor/health")]
        lag99 = max((h.get("lag_ms_p99") or 0.0 for h in reports), default=float("nan"))
        lagmax = max((h.get("lag_ms_max") or 0.0 for h in reports), default=float("nan"))
    finally:
        b.close()
        stop_node(node)
    return {"beds": beds, "offered": r["count"], "wall": r["wall"], "behind_s": r["behind_s"],
            "zenoh_received": zrecv, "zenoh_offered": rz["count"], "zenoh_wall": rz["wall"],
            "zenoh_cpu": zcpu, "cpu": cpu, "health": health, "seen": seen, "lat": lat,
            "lag99": lag99, "lagmax": lagmax, "drain_ms": drain_ms, "slots": len(stream.slots)}


def ms(x: float) -> str:
    return f"{x:.2f} ms"


def report(lat: dict | None, thr: dict | None, nchan: int) -> bool:
    from node.cli.table import print_table
    ok = True
    if lat is not None:
        z, n = lat["zenoh"], lat["node"]
        p99_ok = pct(n, 99) < LATENCY_P99_MS and lat["monitor"] == lat["slots"]
        ok &= p99_ok
        rows = [
            ["latency p50", ms(pct(n, 50)), f"Zenoh alone (echo process) {ms(pct(z, 50))}", ""],
            ["latency p99", ms(pct(n, 99)), f"< {LATENCY_P99_MS:g} ms; Zenoh echo {ms(pct(z, 99))}",
             "PASS" if p99_ok else "FAIL"],
            ["latency max", ms(n.max() if len(n) else float("nan")),
             f"Zenoh echo {ms(z.max() if len(z) else float('nan'))}", ""],
            ["samples measured / monitor messages", f"{len(n)} / {lat['monitor']}",
             f"{lat['slots'] - WARMUP} / {lat['slots']}; echo {lat['zenoh_replies']} / {lat['zenoh_slots']}",
             "PASS" if lat["monitor"] == lat["slots"] else "FAIL"],
        ]
        print_table(["figure", "measured", "ceiling / target", "result"], rows, markdown=True,
                    title="Live latency, 1 test bed: last needed channel published -> monitor message "
                    "received")
    if thr is not None:
        nb, slots = len(thr["beds"]), thr["slots"]
        target_rate = nb * nchan * FS
        health = thr["health"]
        received = sum(h.get("received", 0) for h in health.values())  # health is per bed
        dropped = sum(h.get("dropped", 0) for h in health.values()) if health else -1
        missing = sum(sum(h.get("missing", {}).values()) for h in health.values())
        late = sum(h.get("late", 0) for h in health.values())
        samples = [health.get(b, {}).get("samples", 0) for b in thr["beds"]]
        seen = [thr["seen"].get(b, 0) for b in thr["beds"]]
        kept_up = thr["offered"] / thr["wall"] >= 0.99 * target_rate  # the publisher kept the rate
        checks = {
            "offered": kept_up,
            "received": received == thr["offered"],
            "dropped": dropped == 0,
            "missing": missing == 0 and late == 0 and len(health) == nb and min(samples) == slots,
            "monitor": min(seen) == slots and max(seen) == slots,
        }
        ok &= all(checks.values())

        def res(k: str) -> str:
            return "PASS" if checks[k] else "FAIL"
        rows = [
            ["messages/s offered", f"{thr['offered'] / thr['wall']:,.0f} ({thr['offered']:,} in "
             f"{thr['wall']:.1f} s; publisher at most {thr['behind_s'] * 1e3:.0f} ms late)",
             f"{target_rate:,.0f} ({nb} beds x {nchan} channels x 40 Hz)", res("offered")],
            ["messages received by the node", f"{received:,}",
             f"all offered; bare Zenoh subscriber: {thr['zenoh_received']:,} of {thr['zenoh_offered']:,}",
             res("received")],
            ["queue overflow", str(dropped), "0", res("dropped")],
            ["missing from cadence / late (all beds)", f"{missing} / {late}",
             f"0 / 0; {nb} beds x {slots} samples", res("missing")],
            ["monitor messages per bed (min-max)", f"{min(seen)}-{max(seen)}", f"{slots} each",
             res("monitor")],
            ["node CPU", f"{thr['cpu'] * 100:.0f} % of a core",
             f"bare Zenoh subscriber {thr['zenoh_cpu'] * 100:.0f} %", ""],
            ["worker queue lag p99 (worst health report)", ms(thr["lag99"]), "", ""],
            ["backlog after the last publish", ms(thr["drain_ms"]), "", ""],
            ["latency under load p50 / p99 / max", f"{pct(thr['lat'], 50):.1f} / {pct(thr['lat'], 99):.1f} / "
             f"{pct(thr['lat'], 100):.1f} ms", "", ""],
            ["worker lag max (worst health report)", ms(thr["lagmax"]), "", ""],
        ]
        print_table(["figure", "measured", "ceiling / target", "result"], rows, markdown=True,
                    title=f"Throughput, {nb} test beds at 40 Hz into one node process")
    return ok


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench live")
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_runs.mcap"))
    ap.add_argument("--model")
    ap.add_argument("--seconds", type=float, default=60.0, help="per node measurement (default 60)")
    ap.add_argument("--ceiling-seconds", type=float, default=15.0, help="per Zenoh-only measurement")
    ap.add_argument("--beds", type=int, default=20)
    ap.add_argument("--offset", type=float, default=30.0, help="s into the recording's first run")
    ap.add_argument("--only", choices=["latency", "throughput"])
    args = ap.parse_args(argv)
    from node.cli import main as cli
    from node.models.bundle import load_bundle
    from node.runtime.pipeline import MonitorPipeline

    tmp = Path(tempfile.mkdtemp(prefix="ordervib-live-"))
    if not args.model:
        args.model = str(tmp / "model")
        with contextlib.redirect_stdout(io.StringIO()):  # the training report is not the bench's
            cli(["train", str(ROOT / "recordings" / "engine1_runs.mcap"), "--schedule",
                 str(ROOT / "recordings" / "engine1_runs.schedule.toml"), "--out", args.model,
                 "--method", "lasso", "--target", "yB", "--quiet"])
    bundle = load_bundle(args.model)
    needed = set(MonitorPipeline(bundle).sensor_channels)  # what the test bed publishes
    stream = load_stream(args.recording, args.seconds, args.offset, needed)
    channels = sorted({c for s in stream.slots for c, _ in s})
    print(f"{args.recording}: {len(stream.slots)} samples of {len(channels)} channels per bed "
          f"({len(needed)} needed by the model), from {args.offset:g} s into the first run; "
          f"node recordings in {tmp}")
    lat = thr = None
    if args.only in (None, "latency"):
        lat = run_latency(args, stream, channels, needed, bundle.target, tmp)
    if args.only in (None, "throughput"):
        thr = run_throughput(args, stream, channels, bundle.target, tmp)
    return 0 if report(lat, thr, len(channels)) else 1


if __name__ == "__main__":
    raise SystemExit(main())
