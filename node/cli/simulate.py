"""``ordervib simulate``: pass-off runs of the built-in test-bed simulator, to MCAP.

Writes REC.mcap (contract sections 1 and 3), REC.schedule.toml (section 4) and
REC.truth.json (run times, shutdown times, OC intervals, fault onset, schedule
origin, noise scale). The same seed gives byte-identical files. ``--schedule``
runs the OCs of a contract schedule file instead of the built-in 12;
``--noise-scale`` scales every sensor's noise. The optional order phases
(``yA_ph``, ``yB_ph``, ``yC_ph``, degrees) are written unless ``--no-phase``; every
other channel is the same either way.
"""

from __future__ import annotations

import argparse
import logging
import os
import time

from node.cli.logs import Progress
from node.cli.outputs import check_output, replacing
from simulator.files import Simulation, simulate_files

log = logging.getLogger(__name__)

NAME = "simulate"
HELP = "write pass-off runs of the built-in three-shaft turbofan simulator to an MCAP recording"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from simulator.campaign import FAULTS

    p.add_argument("--runs", type=int, default=3, metavar="N", help="number of runs (default 3)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    p.add_argument("--out", required=True, metavar="REC.mcap", help="output recording")
    p.add_argument(
        "--fault", choices=FAULTS, default=None, help="inject a fault into the last run"
    )
    p.add_argument(
        "--fault-seed",
        type=int,
        default=None,
        metavar="F",
        help="with --fault: draw the fault's onset (OC and time) from seed F (default: from --seed)",
    )
    p.add_argument(
        "--fault-size",
        type=float,
        default=None,
        metavar="X",
        help="with --fault: scale the fault's magnitude by X > 0 (default 1 = nominal): "
        "imbalance adds X x 0.9 x the base imbalance of plane 1; stiffness lowers the 0.95 "
        "mode's stiffness by X x 10 %% over 20 s (X < 10); drift ramps yB by X x 0.5 mm/s "
        "per minute; stuck-sensor ignores it",
    )
    p.add_argument(
        "--schedule",
        default=None,
        metavar="S.toml",
        help="run the OCs of this contract schedule (docs/contract.md section 4; switch \"nB\"; "
        "speeds 2600-9800 rpm, in test order) instead of the built-in 12; each [[oc]] may add "
        "plateau = nominal plateau length in s (default 40) and rate = nominal transition rate "
        "in rpm/s (default 90). The sidecar REC.schedule.toml is then this schedule",
    )
    p.add_argument(
        "--noise-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="multiply every channel's sensor noise sigma (absolute and relative part) by X > 0 "
        "(default 1); recorded in the truth JSON",
    )
    p.add_argument("--bed", default="bed1", metavar="NAME", help="test-bed name (default bed1)")
    p.add_argument(
        "--plateau-scale",
        type=float,
        default=1.0,
        metavar="X",
        help="scale the nominal plateau lengths (default 1; smaller gives shorter runs)",
    )
    p.add_argument(
        "--skip",
        type=int,
        default=0,
        metavar="K",
        help="simulate all runs but write only those after the first K (same engine history)",
    )
    p.add_argument(
        "--channels",
        default=None,
        metavar="LIST",
        help="publish only these channels, comma-separated (default: all 21 of the contract "
        "and the 3 order phases yA_ph, yB_ph, yC_ph)",
    )
    p.add_argument(
        "--no-phase",
        action="store_true",
        help="leave out the order phases yA_ph, yB_ph, yC_ph (a test bed without once-per-rev "
        "reference); the other channels are the same either way",
    )
    p.add_argument(
        "--tracker",
        choices=("fixed", "drawn"),
        default="fixed",
        help="the vibration unit's order-tracker lag: fixed (1 s, default) or drawn per engine "
        "in 0.5-2 s from the seed (stated in the truth JSON's rotor.tracker_s)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _simulation(args: argparse.Namespace) -> Simulation:
    return Simulation(runs=args.runs, seed=args.seed, fault=args.fault, fault_seed=args.fault_seed,
                      fault_size=args.fault_size, schedule=args.schedule, noise_scale=args.noise_scale,
                      bed=args.bed, plateau_scale=args.plateau_scale, skip=args.skip,
                      channels=args.channels, phase=not args.no_phase, tracker=args.tracker)


def run(args: argparse.Namespace) -> int:
    sim = _simulation(args)
    sim.check()
    check_output(args.out, "--out", suffix=".mcap", inputs=[args.schedule] if args.schedule else [])
    start = time.perf_counter()
    progress = Progress(NAME, log)
    with replacing(args.out) as part:
        count, schedule_path, truth_path = simulate_files(sim, args.out, progress, part)
    # the result, on stdout (progress and other status go to stderr)
    print(f"simulate: {args.runs - args.skip} runs, {count} messages -> {args.out} "
          f"(+ {os.path.basename(schedule_path)}, {os.path.basename(truth_path)}) "
          f"in {time.perf_counter() - start:.1f} s")
    return 0
