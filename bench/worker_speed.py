"""The live node's worker alone: the batches it takes, in CPU time, without Zenoh.

    python -m bench worker-speed [--model MODEL] [--beds 20] [--seconds 40] [--offset 30]
                                 [--batch 64] [--repeat 3] [--profile N] [REC.mcap]

``--beds`` test beds each send the first run of the recording (``--seconds`` from ``--offset``),
interleaved as ``bench live`` publishes them (at each 40 Hz slot, bed by bed, every channel),
stamped with receive times 25 ms a slot apart. The messages are cut into batches of ``--batch``
(the worker drains whatever is waiting: in a ``bench live`` run at 20 beds its batches held
62.5 messages on average, median 3, 90th percentile 247: most messages come in batches of
dozens to hundreds; ``--batch 4`` shows the per-batch overhead) and handed to the
live node's own batch step (``LiveNode.handle_batch``: the core's logic, recording every input,
encoding and "publishing" every output to a stand-in publisher that only hashes the bytes, and
recording them). Prints the worker's CPU time a message (``time.process_time``, the best of
``--repeat`` runs, each a fresh node), beside the core's logic alone (``NodeCore.handle_batch``
on the same batches) measured in the same run, and a digest of every output's key and bytes
(what must not change when the path gets cheaper). ``--profile N``: one more run under cProfile,
its N costliest functions by own time.

Without ``--model`` a Lasso bundle is trained on the committed sample runs first. The figure
beside the target (10 us a message for the whole node, the live target) is the worker's share only:
Zenoh's receive side costs about the bare subscriber's figure on top (``bench live``).
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import hashlib
import io
import pstats
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from harness.live import ROOT, load_stream
from node.contract import FS, sensor_key

TARGET_US = 10.0  # the whole node a message (the live target); the worker must stay well under it
SLOT_NS = round(1e9 / FS)
SPREAD_NS = 10_000  # receive-time step between messages of a slot, ns


class _Session:
    """Stands in for a Zenoh session: its puts hash what they are given (key, bytes)."""

    def __init__(self) -> None:
        self.digest = hashlib.sha256()

    def put(self, key: str, data: bytes, **_: object) -> None:
        self.digest.update(key.encode())
        self.digest.update(data)


def batches(recording: str, needed: set[str], beds: int, seconds: float, offset: float,
            size: int) -> list[list[tuple[str, bytes, int]]]:
    """The fleet's messages (key, payload, receive ns) as the worker takes them: ``size`` a batch."""
    stream = load_stream(recording, seconds, offset, needed)
    names = [f"bed{i:02d}" for i in range(1, beds + 1)]
    keys: dict[tuple[str, str], str] = {}
    flat: list[tuple[str, bytes, int]] = []
    for j, slot in enumerate(stream.slots):
        t = 1_000_000_000 + j * SLOT_NS
        for b in names:
            for c, payload in slot:
                key = keys.get((b, c)) or keys.setdefault((b, c), sensor_key(b, c))
                flat.append((key, payload, t))
                t += SPREAD_NS
    return [flat[i:i + size] for i in range(0, len(flat), size)]


def run_worker(model: object, work: list[list[tuple[str, bytes, int]]], tmp: Path,
               profile: cProfile.Profile | None = None) -> tuple[float, str]:
    """CPU seconds of ``LiveNode.handle_batch`` over every batch, and the outputs' digest."""
    from node.live.node import LiveNode, quiet_gc
    path = tmp / f"worker-{time.monotonic_ns()}.mcap"
    node = LiveNode(model, str(path))  # type: ignore[arg-type]
    session = _Session()
    node.attach(session)  # publishes to the stand-in: no Zenoh, no worker thread
    quiet_gc()
    handle: Callable[[list[tuple[str, bytes, int]]], None] = node.handle_batch
    if profile is not None:
        profile.enable()
    t0 = time.process_time()
    for batch in work:
        handle(batch)
    for out in node.core.finish():  # (the live node's end: its last samples, one by one)
        node.publish((out,))
    cpu = time.process_time() - t0
    if profile is not None:
        profile.disable()
    node.writer.close()
    path.unlink()
    gc.unfreeze()
    return cpu, session.digest.hexdigest()


def run_core(model: object, work: list[list[tuple[str, bytes, int]]]) -> tuple[float, int]:
    """CPU seconds of ``NodeCore.handle_batch`` alone over the same batches, and its outputs."""
    from node.live.node import quiet_gc
    from node.runtime.core import NodeCore
    core = NodeCore(model)  # type: ignore[arg-type]
    quiet_gc()
    n = 0
    t0 = time.process_time()
    for batch in work:
        keys, payloads, recv = zip(*batch, strict=True)
        n += sum(len(outs) for _, outs in core.handle_batch(keys, payloads, recv).done)
    n += len(core.finish())
    cpu = time.process_time() - t0
    gc.unfreeze()
    return cpu, n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench worker-speed")
    ap.add_argument("recording", nargs="?", default=str(ROOT / "recordings" / "engine1_fault.mcap"))
    ap.add_argument("--model")
    ap.add_argument("--beds", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--offset", type=float, default=30.0)
    ap.add_argument("--batch", type=int, default=64, help="messages a batch (default 64)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure, the best kept (default 3)")
    ap.add_argument("--sort", default="tottime", choices=("tottime", "cumulative"),
                    help="--profile: order by own time (default) or with callees")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="one more run under cProfile: its N costliest functions")
    args = ap.parse_args(argv)
    for name in ("beds", "batch", "repeat"):
        if not 1 <= getattr(args, name) <= 100_000:
            ap.error(f"--{name} must be in 1..100000")
    if not 0 < args.seconds <= 3600 or not 0 <= args.offset <= 36_000:
        ap.error("--seconds must be in (0, 3600] and --offset in [0, 36000]")
    from harness import make
    from node.models.bundle import load_model

    tmp = Path(tempfile.mkdtemp(prefix="ordervib-worker-"))
    if not args.model:
        args.model = make.sample_model(tmp / "model")
    model = load_model(args.model)
    needed = {c for b in model.bundles for c in (b.schedule.switch, b.target, *b.inputs)}
    work = batches(args.recording, needed, args.beds, args.seconds, args.offset, args.batch)
    n = sum(len(b) for b in work)
    best_worker, best_core = float("inf"), float("inf")
    digests: set[str] = set()
    outputs: set[int] = set()
    for _ in range(args.repeat):  # interleaved, so that a busy moment hits both
        cpu, digest = run_worker(model, work, tmp)
        best_worker, digests = min(best_worker, cpu), digests | {digest}
        cpu, out = run_core(model, work)
        best_core, outputs = min(best_core, cpu), outputs | {out}
    if len(digests) != 1 or len(outputs) != 1:
        raise SystemExit(f"runs disagree: digests {sorted(digests)}, outputs {sorted(outputs)}")
    print(f"{args.recording}: {args.beds} beds x {args.seconds:g} s = {n} messages in batches of "
          f"{args.batch}, {outputs.pop()} outputs; model {args.model} "
          f"({len(model.bundles)} target(s)); best of {args.repeat}, CPU time")
    print("| step | CPU s | us a message |")
    print("|---|---|---|")
    print(f"| the node's logic (NodeCore.handle_batch) | {best_core:.2f} | {best_core / n * 1e6:.2f} |")
    print(f"| the worker (logic, recording, encoding, publishing) | {best_worker:.2f} "
          f"| {best_worker / n * 1e6:.2f} |")
    print(f"outputs sha256 {digests.pop()}")
    us = best_worker / n * 1e6
    print(f"{'PASS' if us <= TARGET_US else 'FAIL'}: the worker alone {us:.2f} us a message "
          f"(the whole node's target {TARGET_US:g} us, Zenoh's receive side not included)")
    if args.profile:
        prof = cProfile.Profile()
        run_worker(model, work, tmp, prof)
        text = io.StringIO()
        pstats.Stats(prof, stream=text).sort_stats(args.sort).print_stats(args.profile)
        print(text.getvalue())
    return 0 if us <= TARGET_US else 1


if __name__ == "__main__":
    raise SystemExit(main())
