"""``ordervib demo``: the whole chain on the embedded default, no router to install.

Simulates one engine's pass-off runs (once; kept in DIR/data): 8 to train on, 2
healthy ones held out, and an 11th with an imbalance fault. Trains every tracked
order (yA, yB, yC) with the defaults (or reuses the model), prints each target's
held-out table against the characteristic-curve baseline, starts the live node on
a loopback endpoint, publishes the fault run through Zenoh, stops the node, and
writes the node's MCAP and a Rerun file.
"""

from __future__ import annotations

import argparse
import logging
import socket
import time
from pathlib import Path

NAME = "demo"
HELP = ("full demo: simulate, train, held-out table, live node over Zenoh on loopback, publish a "
        "fault run, MCAP and .rrd out")
# The demo's engine: seed 1, plateaus a quarter of the nominal (runs of about 5.5 min). The
# fault seed puts the added imbalance where it changes yB visibly (as engine1_fault.mcap's does;
# recordings/README.md says why a seed is picked); bench faults measures random onsets.
SIM = ["--seed", "1", "--plateau-scale", "0.25", "--quiet"]
TRAIN_RUNS, HELD_OUT_RUNS = 8, 2
FAULT = ["--fault", "imbalance", "--fault-seed", "4"]
ROOT = Path(__file__).resolve().parents[2]

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="out/demo", metavar="DIR",
                   help="output folder (default out/demo): new, empty or an earlier demo's; its model, "
                        "node.mcap and node.rrd are replaced only by complete new ones")
    p.add_argument("--method", default="wdmd", choices=["wdmd", "delay-dmd", "lasso"])
    p.add_argument("--speed", type=float, default=0.0,
                   help="publishing speed, x real time (default 0: as fast as the link takes)")
    p.add_argument("--retrain", action="store_true", help="train even if DIR/model exists")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(args: argparse.Namespace) -> int:
    from node.cli import main as cli
    from node.cli.outputs import MODEL_MARKER, replacing
    from node.contract.errors import OrdervibError
    from node.live.node import LiveNode
    from node.models.bundle import load_model
    from replay.publish import publish_recording

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise OrdervibError(f"--out {out} is a file, not a folder")
    ours = (out / "model" / MODEL_MARKER).is_file() or (out / "data" / "train.schedule.toml").is_file()
    if out.is_dir() and any(out.iterdir()) and not ours:
        raise OrdervibError(f"--out {out} holds other files than a demo's: give a new or empty folder")
    out.mkdir(parents=True, exist_ok=True)
    data = out / "data"
    data.mkdir(exist_ok=True)
    rec_train, rec_held, rec_test = data / "train.mcap", data / "heldout.mcap", data / "fault.mcap"
    schedule = data / "train.schedule.toml"
    t0 = time.perf_counter()
    n_all = TRAIN_RUNS + HELD_OUT_RUNS
    for path, argv in ((rec_train, ["--runs", str(TRAIN_RUNS)]),
                       (rec_held, ["--runs", str(n_all), "--skip", str(TRAIN_RUNS)]),
                       (rec_test, ["--runs", str(n_all + 1), "--skip", str(n_all), *FAULT])):
        if not path.exists():
            log.info("[1/5] simulating %s (%s) ...", path.name, " ".join(argv))
            if cli(["simulate", *argv, *SIM, "--out", str(path)]) != 0:
                return 2
    model = out / "model"
    if args.retrain or not _trained_on(model, rec_train, args.method):
        log.info("[2/5] training %s on %s (%d runs) ...", args.method, rec_train.name, TRAIN_RUNS)
        if cli(["train", str(rec_train), "--schedule", str(schedule), "--out", str(model),
                "--method", args.method]) != 0:
            return 2
    else:
        log.info("[2/5] reusing the model in %s, trained on %s (--retrain to train again)", model,
                 rec_train.name)
    log.info("[3/5] held-out runs %s, against the characteristic curve:", rec_held.name)
    if cli(["evaluate", str(model), str(rec_held), "--png", str(out / "evaluation.png"), "--quiet"]) != 0:
        return 2
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    node_rec = out / "node.mcap"
    log.info("[4/5] live node listening on %s, recording to %s", endpoint, node_rec)
    with replacing(str(node_rec)) as part:  # the last demo's recording stays until this one is whole
        node = LiveNode(load_model(model), part, listen=[endpoint])
        node.start()
        try:
            log.info("      publishing %s (a run with an imbalance fault) through Zenoh ...",
                     rec_test.name)
            sent = publish_recording(str(rec_test), endpoint, args.speed, quiet=True)
            deadline = time.monotonic() + 60
            while node.stats.received < sent and time.monotonic() < deadline:
                time.sleep(0.1)
        finally:
            node.stop()
    alarms = sum(b.alarm_samples for b in node.core.beds.values())
    log.info("      node: %d received of %d sent, %d published, %d dropped, %d alarm samples",
             node.stats.received, sent, node.stats.published, node.stats.overflow, alarms)
    log.info("%s", fault_summary(node.core.alarm_log.episodes, rec_test.with_suffix(".truth.json")))
    rrd = out / "node.rrd"
    log.info("[5/5] Rerun file %s, the polar and Bode PNGs of the 1x vector", rrd)
    fleet = load_model(model)["yB"].transients
    lag = fleet.settings.tracker_s if fleet is not None else 0.0  # the lag training estimated
    if cli(["view", str(node_rec), "--save", str(rrd), "--schedule", str(schedule), "--plots", str(out),
            "--tracker-s", repr(lag), "--quiet"]) != 0:
        return 2
    print(f"done in {time.perf_counter() - t0:.0f} s")
    print(f"node recording (MCAP): {node_rec.resolve()}")
    print(f"Rerun file:            {rrd.resolve()}   (open with: rerun {rrd})")
    for png in sorted(out.glob("*-polar.png")) + sorted(out.glob("*-bode.png")):
        print(f"1x vector plot (PNG):  {png.resolve()}")
    print(f"model bundle:          {model.resolve()}")
    return 0


def _trained_on(model: Path, recording: Path, method: str) -> bool:
    """Whether ``model`` is a model of ``method`` trained on exactly ``recording`` (``trained_on``);
    false when it is not there or not a model."""
    from node.contract.errors import OrdervibError
    from node.models.bundle import load_model
    from node.training.provenance import trained_on

    try:
        found = load_model(model)
    except OrdervibError:
        return False
    return all(b.method == method for b in found.bundles) and trained_on(found, [recording])


def fault_summary(episodes: list[dict], truth_path: Path) -> str:
    """One line: the fault's onset (ground truth) against the node's alarm episodes."""
    import json

    try:
        fault = json.loads(truth_path.read_text())["runs"][-1]["fault"]
    except (OSError, KeyError, IndexError, ValueError):
        return "      (no ground truth beside the recording)"
    onset = fault["onset"]
    after = [e for e in episodes if e["end"] >= onset]
    before = len(episodes) - len(after)
    seen = (f"first alarm {max(0.0, after[0]['start'] - onset):.1f} s after it ({after[0]['reason']} rule)"
            if after else "no alarm after it")
    return (f"      truth: {fault['kind']} fault from {fault['onset_s']:.1f} s into the run ({fault['oc']}); "
            f"{seen}; {before} alarm episode(s) before it (false)")

