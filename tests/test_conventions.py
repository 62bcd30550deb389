"""Conventions across commands (issue 34): JSON encoding of every published sample, one schema
name per topic kind, Zenoh option errors in one line, --log-level anywhere, results on stdout."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from node.cli import main

SIM = ["simulate", "--runs", "1", "--plateau-scale", "0.05", "--channels", "nB,yB"]
COMMITTED = Path(__file__).resolve().parents[1] / "recordings" / "engine1_runs.mcap"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("conv") / "sim.mcap"
    assert main([*SIM, "--out", str(out), "--quiet"]) == 0
    return out


def test_replayed_sensor_samples_are_application_json(sim: Path) -> None:
    """`replay --publish` declares its sensor publishers with application/json, as the node does
    (a bare put would say zenoh/bytes)."""
    zenoh = pytest.importorskip("zenoh")
    from node.live.zenoh import open_session, zenoh_config
    from replay.publish import publish_recording

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    encodings: list[str] = []
    session = open_session(zenoh_config([endpoint], None, None))
    sub = session.declare_subscriber("testbed/**", lambda s: encodings.append(str(s.encoding)))
    try:
        sent = publish_recording(str(sim), endpoint, speed=0.0, quiet=True)
        deadline = time.monotonic() + 20
        while len(encodings) < sent and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        sub.undeclare()
        session.close()
    assert sent > 0 and len(encodings) == sent
    assert set(encodings) == {str(zenoh.Encoding.APPLICATION_JSON)}
