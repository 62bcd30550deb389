"""Panel V of the report (``replay.report.transients``): the resonances of every ramp of simulated
runs against the simulator's own crossings, grouped over the runs, with their separation margins."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from node.cli import main
from node.contract.schedule import load_schedule
from node.training.runs import read_runs
from replay.report.document import Figure, Table
from replay.report.transients import crossings, resonances, separation, transient_panel


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("transients") / "t.mcap"
    assert main(["simulate", "--runs", "2", "--seed", "3", "--channels", "nB,yB,yB_ph",
                 "--plateau-scale", "0.1", "--quiet", "--out", str(out)]) == 0
    return out


def test_crossings_match_the_simulators_criticals(sim: Path) -> None:
    runs = read_runs(sim)
    truth = json.loads(sim.with_suffix(".truth.json").read_text())
    found = crossings(runs, "nB", "yB", tracker_tau=truth["rotor"]["tracker_s"])
    assert len(found) >= 4
    for c in found:
        crossed = [x["speed"] for x in truth["runs"][c.run]["criticals"]["yB"]]
        assert min(abs(c.critical.speed / s - 1.0) for s in crossed) < 0.01  # a true crossing, within 1 %
    groups = resonances(found)
    assert len(groups) >= 2
    for g in groups:  # a group spans at most 3 %, and groups are apart by more
        assert max(c.critical.speed for c in g) <= 1.03 * min(c.critical.speed for c in g)
    for a, b in zip(groups, groups[1:]):
        assert b[0].critical.speed > 1.03 * a[0].critical.speed


def test_the_panel_tabulates_resonances_with_their_margins(sim: Path) -> None:
    runs = read_runs(sim)
    schedule = load_schedule(str(sim.with_suffix(".schedule.toml")))
    blocks = transient_panel(runs, ["run 1", "run 2"], schedule, "yB")
    assert sum(isinstance(b, Figure) for b in blocks) == 1
    tables = [b for b in blocks if isinstance(b, Table)]
    assert len(tables) == 2
    summary, detail = tables
    assert len(detail.rows) == len(crossings(runs, "nB", "yB"))
    for row in summary.rows:
        nc = float(row[0].replace(",", ""))
        name, speed, margin = separation(nc, [(o.name, o.speed) for o in schedule.ocs])
        assert row[5] == f"{name} ({speed:,.0f})" and row[6] == f"{margin:.1f} %"


def test_separation_is_from_the_nearest_plateau() -> None:
    name, speed, margin = separation(5000.0, [("a", 4000.0), ("b", 5500.0)])
    assert (name, speed) == ("b", 5500.0) and margin == pytest.approx(100 * 500 / 5500)
