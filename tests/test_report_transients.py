"""Panel V of the report (``replay.report.transients``): the node's own transient analysis of
simulated runs against the simulator's crossings, grouped over the runs, with separation margins."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from node.cli import main
from node.contract.schedule import load_schedule
from node.training.runs import read_runs
from node.training.transients import run_transients, transient_settings
from replay.report.document import Figure, Table
from replay.report.transients import crossings, resonances, separation, transient_panel


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("transients") / "t.mcap"
    assert main(["simulate", "--runs", "2", "--seed", "3", "--channels", "nB,yB,yB_ph",
                 "--plateau-scale", "0.1", "--quiet", "--out", str(out)]) == 0
    return out


def test_crossings_are_the_nodes_and_match_the_simulators_criticals(sim: Path) -> None:
    runs = read_runs(sim)
    schedule = load_schedule(str(sim.with_suffix(".schedule.toml")))
    truth = json.loads(sim.with_suffix(".truth.json").read_text())
    found = crossings(runs, schedule, "yB")
    assert len(found) >= 4
    settings = transient_settings(runs, schedule, "yB")
    for r, run in enumerate(runs):  # the very messages the node publishes over the run
        mine = [c.critical for c in found if c.run == r]
        assert mine == [c for m in run_transients(run, schedule, "yB", settings) for c in m["criticals"]
                        if c["speed"] is not None]
    lag = truth["rotor"]["tracker_s"]  # the order tracker's lag, not undone by the node's default
    for c in found:  # each a true crossing: within 1 % and the ramp's rate times that lag
        crossed = [x["speed"] for x in truth["runs"][c.run]["criticals"]["yB"]]
        slack = abs(c.message["rate"]) * lag
        assert min(abs(c.critical["speed"] - s) - 0.01 * s for s in crossed) < slack
    groups = resonances(found)
    assert 2 <= len(groups) < len(found)
    assert sum(len(g) for g in groups) == len(found)
    for a, b in zip(groups, groups[1:]):  # ascending and apart
        assert min(c.critical["speed"] for c in b) > max(c.critical["speed"] for c in a)


def test_the_panel_tabulates_resonances_with_their_margins(sim: Path) -> None:
    runs = read_runs(sim)
    schedule = load_schedule(str(sim.with_suffix(".schedule.toml")))
    blocks = transient_panel(runs, ["run 1", "run 2"], schedule, "yB")
    assert sum(isinstance(b, Figure) for b in blocks) == 1
    tables = [b for b in blocks if isinstance(b, Table)]
    assert len(tables) == 2
    summary, detail = tables
    assert len(detail.rows) == len(crossings(runs, schedule, "yB"))
    assert all(row[-1] == "no-model" for row in detail.rows)  # no bundle: no fleet to compare with
    for row in summary.rows:
        nc = float(row[0].replace(",", ""))
        name, speed, margin = separation(nc, [(o.name, o.speed) for o in schedule.ocs])
        assert row[5] == f"{name} ({speed:,.0f})" and row[6] == f"{margin:.1f} %"


def test_separation_is_from_the_nearest_plateau() -> None:
    name, speed, margin = separation(5000.0, [("a", 4000.0), ("b", 5500.0)])
    assert (name, speed) == ("b", 5500.0) and margin == pytest.approx(100 * 500 / 5500)
