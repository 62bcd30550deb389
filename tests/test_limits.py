"""Acceptance limits (docs/contract.md sections 2 and 4): the schedule's ``[[limit]]`` tables
checked as inputs are, the limit in force at each sample, and the pass-off verdict."""

from __future__ import annotations

from pathlib import Path

import pytest

from node.cli import main
from node.contract import OrdervibError, load_schedule
from node.contract.schedule import Limit, Schedule, limit_in_force

PLAIN = ('switch = "nB"\ntolerance = 0.02\n[[oc]]\nname = "OC3"\nspeed = 4700.0\n'
         '[[oc]]\nname = "OC7"\nspeed = 8000.0\n')
BAND = '[[limit]]\ntarget = "yB"\nmax = 12.0\nfrom_speed = 7000.0\nto_speed = 9900.0\n'


def _load(tmp_path: Path, text: str) -> Schedule:
    path = tmp_path / "s.toml"
    path.write_text(text, encoding="utf-8")
    return load_schedule(path)


def test_limits_are_read_kept_and_written_back(tmp_path: Path) -> None:
    s = _load(tmp_path, "separation_margin = 0.15\n" + PLAIN + BAND
              + '[[limit]]\ntarget = "yA"\nmax = 4\noc = "rundown"\n')
    assert s.limits == (Limit("yB", 12.0, 7000.0, 9900.0), Limit("yA", 4.0, oc="rundown"))
    assert s.separation_margin == 0.15
    assert s.limits_of("yB") == s.limits[:1]
    assert Schedule.from_dict(s.to_dict()) == s
    assert _load(tmp_path, s.to_toml()) == s
    plain = _load(tmp_path, PLAIN)
    assert "limit" not in plain.to_dict() and plain.limits == () and plain != s


@pytest.mark.parametrize("table, words", [
    ('target = "yB"\nmax = 12.0\nfrom_speed = 9000.0\nto_speed = 7000.0\n', "inverted speed band"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = 7000.0\nto_speed = 7000.0\n', "inverted speed band"),
    ('target = "yB"\nmax = nan\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = inf\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = -1.0\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = 0\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = true\n', "max must be a positive finite number"),
    ('target = "yB"\nmax = "12"\n', "max must be a positive finite number"),
    ('target = "yB"\n', "no max"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = -5.0\n', "from_speed must be a finite number >= 0"),
    ('target = "yB"\nmax = 12.0\nto_speed = inf\n', "to_speed must be a finite number >= 0"),
    ('target = "yB"\nmax = 12.0\nfrom_speed = 7000.0\noc = "OC7"\n', "both a speed band and an oc"),
    ('target = "yB"\nmax = 12.0\noc = "OC9"\n', "oc 'OC9' is none of the schedule's segments"),
    ('target = "yB"\nmax = 12.0\noc = 7\n', "oc must be an OC's name"),
    ('target = "y*"\nmax = 12.0\n', "target must name a channel"),
    ('target = "oc"\nmax = 12.0\n', "target must name a channel"),
    ('max = 12.0\n', "target must name a channel"),
    ('target = "yB"\nmax = 12.0\nto_sped = 9.0\n', "unknown key(s) to_sped"),
])
def test_a_bad_limit_is_a_one_line_error(tmp_path: Path, table: str, words: str) -> None:
    with pytest.raises(OrdervibError) as exc:
        _load(tmp_path, PLAIN + "[[limit]]\n" + table)
    assert words in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("extra, words", [
    ("limit = 3\n", "limit must be an array of tables"),
    ("separation_margin = 1.5\n", "separation_margin must be in (0, 1)"),
    ('separation_margin = "wide"\n', "separation_margin must be a number"),
])
def test_a_bad_limit_setting_is_a_one_line_error(tmp_path: Path, extra: str, words: str) -> None:
    with pytest.raises(OrdervibError) as exc:
        _load(tmp_path, extra + PLAIN)
    assert words in str(exc.value)


def test_a_limit_on_a_target_the_model_lacks_is_refused() -> None:
    s = Schedule.from_dict({"oc": [{"name": "A", "speed": 4000.0}], "limit": [{"target": "yD", "max": 3.0}]})
    s.check_targets(["yD"])
    with pytest.raises(OrdervibError, match="on yD, which the model does not hold"):
        s.check_targets(["yA", "yB"])


def test_train_reports_a_bad_limit_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "r.mcap"
    rec.write_bytes(b"")
    sched = tmp_path / "s.toml"
    sched.write_text(PLAIN + '[[limit]]\ntarget = "yB"\nmax = 12.0\nfrom_speed = 9.0\nto_speed = 1.0\n')
    assert main(["train", str(rec), "--schedule", str(sched), "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ordervib train: ") and "inverted speed band" in err and len(err.splitlines()) == 1


def test_the_limit_in_force_is_the_smallest_that_applies() -> None:
    limits = (Limit("yB", 12.0, 7000.0, 9900.0), Limit("yB", 10.0, oc="OC7"), Limit("yB", 20.0),
              Limit("yB", 11.0, from_speed=9000.0))
    assert limit_in_force(limits, 8000.0, "OC7") == 10.0
    assert limit_in_force(limits, 7000.0, "OC3") == 12.0  # band ends included
    assert limit_in_force(limits, 9950.0, "OC3") == 11.0  # one end alone: open on the other
    assert limit_in_force(limits, 100.0, None) == 20.0  # everywhere
    assert limit_in_force(limits[:2], 100.0, None) is None
