"""The live node's transient analyses in a process of their own: the same messages, in order,
and nothing lost when that process dies."""

import logging
import os
import signal

import numpy as np
import pytest

from node.contract.schedule import OperatingCondition, Schedule
from node.live.analyses import TransientAnalyses
from node.runtime.transient_watch import TransientWatch


def _pending(peak_rpm: float):
    """A ramp up through one resonance at ``peak_rpm``: its PendingTransient."""
    w = TransientWatch("yB", Schedule((OperatingCondition("A", 9000.0),)), None)
    w.defer = True
    speed = np.concatenate([np.full(200, 3000.0), np.linspace(3000, 9000, 2400), np.full(400, 9000.0)])
    r = speed / peak_rpm
    amp = np.abs(speed * r**2 / (1 - r**2 + 0.1j * r) * 1e-3)
    out = [w.step(k / 40, s, s, a, None) for k, (s, a) in enumerate(zip(speed, amp, strict=True))]
    (pending,) = [p for p in out if p is not None]
    return pending


@pytest.fixture(scope="module")
def ramps():
    return [_pending(rpm) for rpm in (5000.0, 6000.0, 7000.0)]


def test_messages_from_the_process_equal_the_inline_ones_in_order(ramps):
    analyses = TransientAnalyses()
    try:
        for i, p in enumerate(ramps):
            analyses.submit(f"k{i}", p)
        got = analyses.done(wait=True)
        (child,) = analyses._pool._processes  # one process, at the lowest priority
        with open(f"/proc/{child}/stat") as f:
            assert int(f.read().rsplit(")", 1)[1].split()[16]) == 19  # its nice value
    finally:
        analyses.close()
    assert [k for k, _ in got] == ["k0", "k1", "k2"]
    assert [m for _, m in got] == [p.resolve() for p in ramps]  # to the last bit
    assert [round(m["criticals"][0]["speed"], -2) for _, m in got] == [5000.0, 6000.0, 7000.0]
    assert analyses.waiting == 0 and not analyses.inline


def test_a_dead_analysis_process_loses_nothing_and_says_so_once(ramps, caplog):
    analyses = TransientAnalyses()
    try:
        analyses.submit("k0", ramps[0])
        assert analyses.done(wait=True)[0][0] == "k0"  # the process runs
        assert analyses._pool is not None
        for pid in list(analyses._pool._processes):  # killed from outside (OOM killer, say)
            os.kill(pid, signal.SIGKILL)
        with caplog.at_level(logging.WARNING, logger="node.live.analyses"):
            for i, p in enumerate(ramps):
                analyses.submit(f"k{i}", p)
            got = analyses.done(wait=True)
    finally:
        analyses.close()
    assert [k for k, _ in got] == ["k0", "k1", "k2"]
    assert [m for _, m in got] == [p.resolve() for p in ramps]
    assert analyses.inline and sum("their process failed" in r.message for r in caplog.records) == 1


def test_beyond_the_bound_the_caller_analyses_at_once(ramps):
    analyses = TransientAnalyses(inline=True)
    analyses.submit("a", ramps[0])
    assert analyses.waiting == 1 and analyses._pool is None
    assert analyses.done() == [("a", ramps[0].resolve())]
    bounded = TransientAnalyses(waiting_max=0)  # never more than 0 waiting in the process
    bounded.submit("b", ramps[1])
    assert bounded._pool is None and bounded.done() == [("b", ramps[1].resolve())]


def test_the_analysis_process_ends_with_a_node_killed_outright(tmp_path):
    """A node that dies without stopping (SIGKILL, os._exit) leaves no analysis process behind."""
    import subprocess
    import sys
    import time

    script = tmp_path / "node_that_dies.py"
    script.write_text(
        "import os, sys\n"
        f"sys.path[:0] = [{str(__import__('pathlib').Path(__file__).parent)!r}]\n"
        "from test_analyses import _pending\n"
        "from node.live.analyses import TransientAnalyses\n"
        "if __name__ == '__main__':\n"
        "    a = TransientAnalyses()\n"
        "    a.submit('k', _pending(6000.0))\n"
        "    assert a.done(wait=True)[0][0] == 'k'\n"
        "    print(*a._pool._processes, flush=True)\n"
        "    os._exit(0)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    (child,) = map(int, out.stdout.split())

    def alive() -> bool:
        try:
            with open(f"/proc/{child}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False
    deadline = time.monotonic() + 30  # (a bound on the wait, not a timing assertion)
    while alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not alive(), f"analysis process {child} outlived its node"
