"""The ``ordervib`` dispatcher: --version, --log-level, bad options, status through logging."""

from __future__ import annotations

import argparse
import importlib
import io
import json
import logging
from pathlib import Path

import pytest

from node import __version__
from node.cli import COMMAND_MODULES, build_parser, main
from node.cli.logs import Progress, StderrHandler, command_logging

SIM = ["simulate", "--runs", "1", "--plateau-scale", "0.05"]


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out == f"ordervib {__version__}\n"


@pytest.mark.parametrize("argv", [["--log-level", "loud", "simulate", "--out", "x.mcap"],
                                  ["--no-such-option"], ["simulate", "--out", "x.mcap", "--runs", "two"]])
def test_bad_option_is_one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ordervib")


def test_status_goes_to_stderr_through_logging(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                               caplog: pytest.LogCaptureFixture) -> None:
    out = tmp_path / "x.mcap"
    with caplog.at_level(logging.INFO):
        assert main([*SIM, "--out", str(out)]) == 0
    res = capsys.readouterr()
    lines = res.err.splitlines()
    assert "\r" not in res.err  # stderr is no terminal here: progress as plain lines
    assert lines[-1].startswith("simulate: 100% (took ")
    assert any(r.name == "node.cli.simulate" and r.getMessage() == lines[-1] for r in caplog.records)
    # the result (what was written) is no status: it goes to stdout (issue 34)
    assert res.out.startswith("simulate: 1 runs, ") and f"-> {out} " in res.out
    assert len(res.out.splitlines()) == 1
    # the handler is gone once the command is over
    assert not any(isinstance(h, StderrHandler) for h in logging.getLogger().handlers)


@pytest.mark.parametrize("option", [["--log-level", "warning"], ["--log-level", "error"], ["QUIET"]])
def test_warning_level_and_quiet_silence_status(option: list[str], tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    argv = [*SIM, "--out", str(tmp_path / "x.mcap")]
    argv = [*argv, "--quiet"] if option == ["QUIET"] else [*option, *argv]
    assert main(argv) == 0
    assert capsys.readouterr().err == ""


def test_error_line_is_unchanged(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--log-level", "error", "simulate", "--out", str(tmp_path / "x.txt")]) == 2
    assert capsys.readouterr().err == f"ordervib simulate: --out must name a .mcap file, got " \
                                      f"{str(tmp_path / 'x.txt')!r}\n"


def test_debug_level_and_nesting(capsys: pytest.CaptureFixture[str]) -> None:
    log = logging.getLogger("node.test")
    with command_logging("debug"):
        log.debug("outer debug")
        with command_logging(None):  # a command run by a command keeps its level
            log.debug("inner debug")
        with command_logging(None, quiet=True):
            log.info("hidden")
            log.warning("shown")
        log.debug("outer again")
    log.warning("after")  # no handler of ours any more
    assert capsys.readouterr().err.splitlines() == ["outer debug", "inner debug", "warning: shown",
                                                    "outer again"]
    assert logging.getLogger("node").level == logging.NOTSET


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_on_a_terminal_is_ended_before_a_log_line(monkeypatch: pytest.MonkeyPatch) -> None:
    tty = _Tty()
    monkeypatch.setattr("sys.stderr", tty)
    log = logging.getLogger("node.test")
    with command_logging("info"):
        now = [0.0]
        progress = Progress("work", log, clock=lambda: now[0])
        progress(0.5)
        log.info("meanwhile")
        now[0] = 3.0
        progress(1.0)
    assert tty.getvalue() == (f"\rwork: [{'#' * 12:<25}] {'50%':<48}\nmeanwhile\n"
                              f"\rwork: [{'#' * 25}] {'100% (took 3 s)':<48}\n")


def test_progress_lines_carry_the_rate_and_the_time_left_and_come_by_step_or_by_time(caplog):
    import logging

    from node.cli.logs import Progress

    now = [100.0]
    p = Progress("train", logging.getLogger("node.cli.test_progress"), step=50, every_s=30.0,
                 clock=lambda: now[0])
    with caplog.at_level(logging.INFO):
        p(0.0, 0, "OCs")  # the start: no line
        now[0] += 10.0
        p(0.1, 1, "OCs")  # neither 50 % nor 30 s: no line
        now[0] += 25.0
        p(0.2, 2, "OCs")  # 35 s since the last line: a line
        now[0] += 5.0
        p(0.5, 5, "OCs")  # the 50 % step
        now[0] += 40.0
        p(1.0, 10, "OCs")
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["train: 20% (2 OCs, 0.057 OCs/s, 2 min 20 s left)",
                     "train: 50% (5 OCs, 0.12 OCs/s, 40 s left)",
                     "train: 100% (10 OCs, 0.12 OCs/s, took 1 min 20 s)"]


# -- conventions for every sub-command: unknown flags, stdout and stderr, --json ------------------------
COMMANDS = [importlib.import_module(m).NAME for m in COMMAND_MODULES]


def test_the_conventions_cover_every_sub_command_of_the_help() -> None:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert sorted(sub.choices) == sorted(COMMANDS) and len(COMMANDS) == 14


@pytest.mark.parametrize("flag", ["--no-such-flag", "--no-such-flag=3"])
@pytest.mark.parametrize("command", COMMANDS)
def test_an_unknown_flag_is_named_under_the_sub_command(command: str, flag: str,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Before: 10 sub-commands reported it as missing arguments, all under "ordervib: error:"."""
    with pytest.raises(SystemExit) as exc:
        main([command, flag])
    assert exc.value.code == 2
    res = capsys.readouterr()
    assert res.err == f"ordervib {command}: error: unrecognized arguments: {flag}\n"
    assert "Traceback" not in res.err and res.out == ""


@pytest.mark.parametrize("argv, message", [
    (["predict", "--model", "M", "--profile", "P.csv", "--out", "O.csv", "--bogus"],
     "ordervib predict: error: unrecognized arguments: --bogus"),  # after every required one
    (["train", "--bogus", "--out", "m"], "ordervib train: error: unrecognized arguments: --bogus"),
    (["train", "--out", "m"], "ordervib train: error: the following arguments are required: REC.mcap"),
    (["native", "bogus"], "ordervib native: error: argument action: invalid choice: 'bogus'"),
    (["simulate", "--out", "x.mcap", "--runs", "two"], "ordervib simulate: error: argument --runs: invalid"),
    (["--bogus", "simulate", "--out", "x.mcap"], "ordervib: error: unrecognized arguments: --bogus"),
])
def test_other_bad_arguments_keep_their_message_under_the_right_prefix(
        argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and len(err.splitlines()) == 1, err


def test_a_sub_command_help_still_prints_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["predict", "--help", "--no-such-flag"])
    assert exc.value.code == 0 and "--json" in capsys.readouterr().out


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from conftest import small_campaign

    return small_campaign(tmp_path_factory.mktemp("conventions"), seed=7)


def test_run_prints_its_closing_summary_on_stdout(campaign: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("zenoh")
    from test_conventions import free_port

    rec = tmp_path / "node.mcap"
    assert main(["run", "--model", str(campaign / "m"), "--record", str(rec), "--listen",
                 f"tcp/127.0.0.1:{free_port()}", "--duration", "1"]) == 0
    res = capsys.readouterr()
    assert res.out == f"stopped: 0 received, 0 published, 0 dropped; {rec} finished\n"
    assert "stopped" not in res.err and "ordervib node on" in res.err  # status stays on stderr


def test_replay_says_the_missing_samples_in_words_and_json(campaign: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["replay", str(campaign / "test.mcap"), "--model", str(campaign / "m"), "--workers", "0"]
    assert main(argv) == 0
    res = capsys.readouterr()
    bed = res.out.splitlines()[1]
    assert bed.startswith("  bed1: ") and ("none missing" in bed or "missing nB" in bed or "missing " in bed)
    assert "{" not in res.out and "'" not in res.out  # no Python repr
    assert main([*argv, "--json", "--quiet"]) == 0
    res = capsys.readouterr()
    data = json.loads(res.out)
    assert data["beds"]["bed1"]["samples"] > 0 and isinstance(data["beds"]["bed1"]["missing"], dict)
    assert data["out"] is None and data["inputs"] > 0 and res.err == ""


def test_evaluate_json_is_one_valid_object_with_its_tables(campaign: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "e.png"
    assert main(["evaluate", str(campaign / "m"), str(campaign / "test.mcap"), "--png", str(png), "--json",
                 "--quiet"]) == 0
    res = capsys.readouterr()
    data = json.loads(res.out)  # NaN written as null: strict JSON
    table = data["yB held-out"]
    assert [row["OC"] for row in table] and all("held-out eps_td" in row for row in table)
    assert data["plots"] == [str(png)] and isinstance(data["false_alarms"], str)
    assert "Traceback" not in res.err
