"""``ordervib run`` with the TLS example configs of docs/zenoh/: a TLS test bed gets through, others do not.

A throwaway CA and node certificate are made with the openssl CLI (the commands of
docs/zenoh/README.md); the node listens only on a tls/127.0.0.1 endpoint given by its
config file (no --listen), the test bed publishes with ``replay --publish --zenoh-config``.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import orjson
import pytest
from conftest import small_campaign

from node.cli import main
from node.contract import MONITOR_SUBSCRIPTION
from node.mcap import iter_messages

pytest.importorskip("zenoh")
if shutil.which("openssl") is None:
    pytest.skip("the openssl CLI is needed to make the test certificates", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "zenoh"


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def make_certs(d: Path) -> None:
    """A CA and a node certificate for IP:127.0.0.1 and DNS:localhost (as in docs/zenoh/README.md)."""
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    openssl("req", "-x509", *ec, "-days", "2", "-subj", "/CN=ordervib test CA",
            "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
            "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=d)
    (d / "node.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n"
                                "basicConstraints=critical,CA:FALSE\n"
                                "keyUsage=critical,digitalSignature,keyEncipherment\n"
                                "extendedKeyUsage=serverAuth\n")
    openssl("req", "-new", *ec, "-subj", "/CN=ordervib-node", "-keyout", "node-key.pem",
            "-out", "node.csr", cwd=d)
    openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
            "-CAcreateserial", "-days", "2", "-extfile", "node.ext", "-out", "node.pem", cwd=d)


def example_config(name: str, d: Path, endpoint: str, old_endpoint: str) -> Path:
    """docs/zenoh/<name> with this test's certificates and endpoint."""
    text = (DOCS / name).read_text()
    assert old_endpoint in text and "/etc/ordervib/tls/" in text
    out = d / name
    out.write_text(text.replace(old_endpoint, endpoint).replace("/etc/ordervib/tls/", f"{d}/"))
    return out


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("tls")
    make_certs(d)
    return small_campaign(d, 3)


def test_tls_node_serves_a_tls_test_bed_and_nobody_else(setup, tmp_path):
    from node.edges.zenoh import open_session, zenoh_config
    endpoint = f"tls/127.0.0.1:{free_port()}"
    node_conf = example_config("tls-node.json5", setup, endpoint, "tls/0.0.0.0:7447")
    bed_conf = example_config("tls-testbed.json5", setup, endpoint, "tls/localhost:7447")
    rec = tmp_path / "node.mcap"
    # no --listen: the node listens on the config file's TLS endpoint only
    proc = subprocess.Popen([sys.executable, "-m", "node.cli", "run", "--model", str(setup / "m"),
                             "--record", str(rec), "--zenoh-config", str(node_conf)],
                            cwd=ROOT, stderr=subprocess.PIPE, text=True)
    sent = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")]
    sessions = []
    try:
        banner: list[str] = []  # printed once the session is open and the subscriber declared
        reader = threading.Thread(target=lambda: banner.append(proc.stderr.readline()), daemon=True)
        reader.start()
        reader.join(timeout=30)
        assert banner and "ordervib node on" in banner[0], f"node did not start: {banner}"

        # intruders on the same port: plain TCP, and TLS without the node's CA
        (tmp_path / "no-ca.json5").write_text(json.dumps({"transport": {"link": {"tls": {}}}}))
        intruder_pubs = []
        for ep, conf_file in ((endpoint.replace("tls/", "tcp/"), None),
                              (endpoint, str(tmp_path / "no-ca.json5"))):
            conf = zenoh_config(None, [ep], conf_file)
            conf.insert_json5("listen/endpoints", "[]")
            s = open_session(conf)
            sessions.append(s)
            intruder_pubs.append(s.declare_publisher("testbed/intruder/sensor/nB"))

        # the TLS test bed's view of the node's output
        lock = threading.Lock()
        got: dict = {"monitor": 0, "health": {}}

        def on_monitor(sample) -> None:
            with lock:
                if str(sample.key_expr).endswith("/health"):
                    got["health"] = orjson.loads(sample.payload.to_bytes())
                else:
                    got["monitor"] += 1
        watcher = open_session(zenoh_config(None, None, str(bed_conf)))
        sessions.append(watcher)
        watcher.declare_subscriber(MONITOR_SUBSCRIPTION, on_monitor)

        time.sleep(0.5)  # the intruders have had time to try
        for pub in intruder_pubs:
            assert not pub.matching_status.matching
            for i in range(20):
                pub.put(orjson.dumps({"t": 1000.0 + i, "v": 1.0}))

        assert main(["replay", str(setup / "test.mcap"), "--publish", "--zenoh-config", str(bed_conf),
                     "--speed", "0", "--quiet"]) == 0
        deadline = time.monotonic() + 20
        while got["health"].get("received", -1) < len(sent) and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
        for s in sessions:
            s.close()
    assert proc.returncode == 0, err
    assert got["monitor"] > 100, f"monitor messages back over TLS: {got['monitor']}"
    assert got["health"].get("received") == len(sent), got["health"]
    recorded = [(m.topic, bytes(m.payload)) for m in iter_messages(rec) if "/sensor/" in m.topic]
    assert sorted(recorded) == sorted(sent)  # every TLS input, and nothing from the intruders
