"""The ``ordervib`` dispatcher: --version, --log-level, bad options, status through logging."""

from __future__ import annotations

import io
import logging
from pathlib import Path

import pytest

from node import __version__
from node.cli import main
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
