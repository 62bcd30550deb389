"""The live view (``ordervib view --connect``): a node's topics streamed to Rerun as they come."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from node.cli import main

pytest.importorskip("rerun")
from test_view import NO_PHASE_ENTITIES, _entities, _verify, node_rec  # noqa: E402,F401 - the fixture


def _messages(rec: Path) -> list[tuple[str, bytes]]:
    with open(rec, "rb") as f:
        return [(c.topic, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=True)]


def test_the_live_view_logs_each_stretch_once_as_the_file_view_does(node_rec: Path, tmp_path: Path,
                                                                     capsys) -> None:
    """Fed a node recording in three stretches with a refresh after each, the live view logs
    every sample once (its counts add up to the file view's) and the same entities."""
    import rerun as rr

    from replay.views.live_view import LiveView

    msgs = _messages(node_rec)
    rr.init("ordervib_view_test", spawn=False)
    out = tmp_path / "live.rrd"
    rr.save(str(out))
    view = LiveView()
    assert view.refresh() is None  # nothing yet
    totals: dict[str, int] = {}
    cuts = [0, len(msgs) // 3, 2 * len(msgs) // 3, len(msgs)]
    for lo, hi in zip(cuts, cuts[1:]):
        for topic, data in msgs[lo:hi]:
            view.add(topic, data)
        counts = view.refresh(final=hi == len(msgs))
        assert counts is not None
        for k in ("speed", "monitor", "alarm", "health"):
            totals[k] = totals.get(k, 0) + counts.get(k, 0)
    rr.disconnect()
    assert main(["view", str(node_rec), "--save", str(tmp_path / "file.rrd")]) == 0
    line = capsys.readouterr().out
    assert f"nB {totals['speed']} samples" in line and f"monitor {totals['monitor']} " in line
    assert totals["monitor"] == 3200 and f"({totals['alarm']} alarm)" in line
    _verify(out)
    printed = _entities(out)
    assert all(e in printed for e in NO_PHASE_ENTITIES)


def test_view_connect_streams_a_running_bed_into_a_rerun_file(node_rec: Path, tmp_path: Path,
                                                                capsys) -> None:
    """Over Zenoh on loopback: a publisher (standing in for the node and the bed) sends the
    recording's topics while ``view --connect --duration --save`` runs; the file holds them."""
    import socket

    import zenoh

    from node.edges.zenoh import open_session, zenoh_config

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    session = open_session(zenoh_config([endpoint], None))
    out = tmp_path / "live.rrd"
    codes: list[int] = []
    try:
        viewer = threading.Thread(target=lambda: codes.append(main(
            ["view", "--connect", endpoint, "--duration", "8", "--refresh", "0.5", "--save", str(out)])))
        viewer.start()
        matched = threading.Event()
        probe = session.declare_publisher("testbed/b1/sensor/nB")
        listener = probe.declare_matching_listener(lambda s: matched.set() if s.matching else None)
        assert matched.wait(6.0), "the live view never subscribed"
        pubs: dict[str, zenoh.Publisher] = {}
        for topic, data in _messages(node_rec):
            if topic not in pubs:
                pubs[topic] = session.declare_publisher(
                    topic, congestion_control=zenoh.CongestionControl.BLOCK)
            pubs[topic].put(data)
        viewer.join(30.0)
        listener.undeclare()
    finally:
        session.close()
    assert codes == [0]
    line = capsys.readouterr().out
    assert f"from {endpoint}" in line and "nB 3200 samples" in line and "monitor 3200 " in line, line
    assert out.exists() and not Path(str(out) + ".part").exists()
    _verify(out)


@pytest.mark.parametrize("argv", [
    ["view"],  # neither a recording nor --connect
    ["view", "REC", "--connect", "tcp/127.0.0.1:1"],  # both
    ["view", "REC", "--duration", "3"],  # a live option without --connect
    ["view", "--connect", "tcp/127.0.0.1:1", "--plots", "."],
    ["view", "--connect", "tcp/127.0.0.1:1", "--duration", "0"],
])
def test_bad_live_view_options_are_one_line(argv: list[str], node_rec: Path, capsys) -> None:
    argv = [str(node_rec) if a == "REC" else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ordervib view:"), err
