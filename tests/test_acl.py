"""The access control shipped in docs/zenoh/ (acl-router.json5, acl-node.json5, acl-testbed.json5).

A router session (as ``ordervib router --zenoh-config`` opens it) loads the shipped router file,
clients the shipped node and test-bed files; only the certificate paths and the port are
substituted. Certificates (a CA, the router's, and client certificates whose common names are
the subjects: ``bed1``, ``ordervib-node``, ``dashboard``, ``stranger``) are made with the
openssl CLI as docs/zenoh/README.md says, everything on loopback.

Every "does not arrive" is checked after a later, allowed message on the same subscriber has
arrived (a positive control), so no test waits on a timeout to pass; arrivals wait at most
``WAIT`` seconds.
"""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import pytest
from test_tls import free_port, openssl  # the same helpers as the TLS test

from node.cli import build_parser
from node.cli.router import router_config
from node.edges.zenoh import open_session, zenoh_config

pytest.importorskip("zenoh")
if shutil.which("openssl") is None:
    pytest.skip("the openssl CLI is needed to make the test certificates", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "zenoh"
DOC_DIR = "/etc/ordervib/tls/"
WAIT = 15.0  # seconds: the longest wait for a message or a declaration to arrive (a loaded CI machine)
EC = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]


def make_cert(d: Path, name: str, cn: str, ext: str) -> None:
    """``name``.pem and ``name``-key.pem for common name ``cn``, signed by the CA in ``d``."""
    (d / f"{name}.ext").write_text(ext + "basicConstraints=critical,CA:FALSE\n"
                                   "keyUsage=critical,digitalSignature,keyEncipherment\n")
    openssl("req", "-new", *EC, "-subj", f"/CN={cn}", "-keyout", f"{name}-key.pem",
            "-out", f"{name}.csr", cwd=d)
    openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
            "-CAcreateserial", "-days", "2", "-extfile", f"{name}.ext", "-out", f"{name}.pem", cwd=d)


def make_certs(d: Path) -> None:
    """The CA, the router's certificate (127.0.0.1, localhost) and one per client common name."""
    openssl("req", "-x509", *EC, "-days", "2", "-subj", "/CN=ordervib test CA",
            "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
            "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=d)
    make_cert(d, "router", "ordervib-router",
              "subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n")
    for cn in ("bed1", "ordervib-node", "dashboard", "stranger"):
        make_cert(d, cn, cn, "extendedKeyUsage=clientAuth\n")


def shipped(name: str, d: Path, port: int, cn: str | None = None) -> Path:
    """docs/zenoh/``name`` with this test's certificate folder and port (and client ``cn``)."""
    text = (DOCS / name).read_text()
    assert ":7447\"" in text and DOC_DIR in text
    text = text.replace("0.0.0.0:7447", f"127.0.0.1:{port}").replace(":7447\"", f":{port}\"")
    text = text.replace(DOC_DIR, f"{d}/")
    if cn is not None:
        own = "ordervib-node" if name == "acl-node.json5" else "bed1"
        assert f"{d}/{own}.pem" in text
        text = text.replace(f"{d}/{own}.pem", f"{d}/{cn}.pem").replace(f"{d}/{own}-key.pem",
                                                                        f"{d}/{cn}-key.pem")
    out = d / f"{name}.{cn or 'own'}.json5"
    out.write_text(text)
    return out


def router_conf(path: Path):
    """The config ``ordervib router --zenoh-config PATH`` opens (no --listen: the file's)."""
    conf, listen = router_config(build_parser().parse_args(["router", "--zenoh-config", str(path)]))
    assert listen == [f"tls/127.0.0.1:{port_of(path)}"]  # the file's TLS endpoint, no tcp/ default
    return conf


def port_of(path: Path) -> int:
    return int(path.read_text().split('endpoints: ["tls/127.0.0.1:')[1].split('"')[0])


class Inbox:
    """A subscriber's received (key, payload) pairs, with a bounded wait for one."""

    def __init__(self) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()

    def __call__(self, sample) -> None:  # noqa: ANN001 - a zenoh.Sample
        with self.cond:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
            self.cond.notify_all()

    def wait_for(self, key: str, payload: bytes) -> bool:
        end = time.monotonic() + WAIT
        with self.cond:
            while (key, payload) not in self.got:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(left)
        return True

    def keys(self) -> set[str]:
        with self.cond:
            return {k for k, _ in self.got}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """The router with the shipped acl-router.json5; a function to open a client session."""
    d = tmp_path_factory.mktemp("acl")
    make_certs(d)
    port = free_port()
    router = open_session(router_conf(shipped("acl-router.json5", d, port)))
    sessions = [router]

    def client(cn: str):
        name = "acl-node.json5" if cn == "ordervib-node" else "acl-testbed.json5"
        s = open_session(zenoh_config(None, None, str(shipped(name, d, port, cn))))
        sessions.append(s)
        return s
    yield client
    for s in reversed(sessions):
        s.close()


def matched(pub) -> bool:  # noqa: ANN001 - a zenoh.Publisher
    end = time.monotonic() + WAIT
    while not pub.matching_status.matching and time.monotonic() < end:
        time.sleep(0.01)
    return pub.matching_status.matching


def test_the_shipped_clients_are_zenoh_clients_and_the_router_a_router(tmp_path):
    """A client talks to its router only: ordervib keeps the files' mode "client"."""
    import json
    port = free_port()
    assert zenoh_config(None, None, str(shipped("acl-node.json5", tmp_path, port))).get_json("mode") \
        == json.dumps("client")
    assert zenoh_config(None, None, str(shipped("acl-testbed.json5", tmp_path, port))).get_json("mode") \
        == json.dumps("client")
    router = router_conf(shipped("acl-router.json5", tmp_path, port))
    assert router.get_json("mode") == json.dumps("router")
    assert json.loads(router.get_json("access_control/enabled")) is True
    assert zenoh_config().get_json("mode") == json.dumps("peer")  # no file: a peer, as before


def test_a_bed_publishes_its_own_sensors_only(fleet):
    bed, node, dash = fleet("bed1"), fleet("ordervib-node"), fleet("dashboard")
    at_node, at_dash = Inbox(), Inbox()
    node.declare_subscriber("testbed/*/sensor/**", at_node)
    for key in ("testbed/*/sensor/**", "testbed/*/monitor/**", "ordervib/node/**"):
        dash.declare_subscriber(key, at_dash)
    pub = bed.declare_publisher("testbed/bed1/sensor/nB")
    assert matched(pub)
    pub.put(b"1")
    assert at_node.wait_for("testbed/bed1/sensor/nB", b"1")
    assert at_dash.wait_for("testbed/bed1/sensor/nB", b"1")

    denied = ["testbed/other-bed/sensor/nB",     # another bed's sensors
              "testbed/*/sensor/nB",             # every bed's, by a wildcard key
              "testbed/bed1/**",                 # wider than its sensors
              "testbed/bed1/monitor/yB",         # the node's outputs, even its own bed's
              "testbed/bed1/monitor/health",
              "testbed/bed1/monitor/oc",
              "ordervib/node/fake/health"]       # a node's own health
    for key in denied:
        bed.put(key, b"fake")
    pub.put(b"2")  # the positive control, sent after the denied ones on the same link
    assert at_node.wait_for("testbed/bed1/sensor/nB", b"2")
    assert at_dash.wait_for("testbed/bed1/sensor/nB", b"2")
    assert at_node.keys() == {"testbed/bed1/sensor/nB"}
    assert at_dash.keys() == {"testbed/bed1/sensor/nB"}


def test_only_the_node_publishes_monitor_topics_and_its_health(fleet):
    node, dash = fleet("ordervib-node"), fleet("dashboard")
    at_dash = Inbox()
    for key in ("testbed/*/sensor/**", "testbed/*/monitor/**", "ordervib/node/**"):
        dash.declare_subscriber(key, at_dash)
    allowed = ["testbed/bed1/monitor/yB", "testbed/other-bed/monitor/oc",
               "testbed/bed1/monitor/health", "ordervib/node/abc/health"]
    pubs = [node.declare_publisher(k) for k in allowed]
    assert [str(p.key_expr) for p in pubs if not matched(p)] == []
    for p in pubs:
        p.put(b"node")
    for key in allowed:
        assert at_dash.wait_for(key, b"node"), key

    node.put("testbed/bed1/sensor/nB", b"fake")  # the node does not publish sensors
    pubs[0].put(b"control")
    assert at_dash.wait_for("testbed/bed1/monitor/yB", b"control")
    assert "testbed/bed1/sensor/nB" not in at_dash.keys()


def test_an_unknown_common_name_neither_publishes_nor_subscribes(fleet):
    """A certificate from the fleet's CA whose CN no subject names (``stranger``)."""
    stranger, bed, node, dash = fleet("stranger"), fleet("bed1"), fleet("ordervib-node"), fleet("dashboard")
    at_node, at_dash, at_stranger = Inbox(), Inbox(), Inbox()
    node.declare_subscriber("testbed/*/sensor/**", at_node)
    dash.declare_subscriber("testbed/*/monitor/**", at_dash)
    reader = fleet("stranger")  # a second session: the first one's own puts would loop back
    for key in ("testbed/*/sensor/**", "testbed/*/monitor/**", "ordervib/node/**"):
        reader.declare_subscriber(key, at_stranger)
    bed_pub = bed.declare_publisher("testbed/bed1/sensor/nB")
    assert matched(bed_pub)
    for key in ("testbed/stranger/sensor/nB", "testbed/bed1/sensor/nB", "testbed/bed1/monitor/yB"):
        stranger.put(key, b"stranger")
    # controls, sent after the stranger's puts: a bed's sample and the node's output
    bed_pub.put(b"control")
    node.put("testbed/bed1/monitor/yB", b"control")
    assert at_node.wait_for("testbed/bed1/sensor/nB", b"control")
    assert at_dash.wait_for("testbed/bed1/monitor/yB", b"control")
    assert all(p != b"stranger" for _, p in at_node.got + at_dash.got)
    assert at_stranger.got == []


def test_only_the_node_holds_a_node_liveliness_token(fleet):
    bed, node, dash = fleet("bed1"), fleet("ordervib-node"), fleet("dashboard")
    tokens = Inbox()
    dash.declare_subscriber("testbed/*/sensor/**", tokens)  # the control's way in
    dash.liveliness().declare_subscriber("ordervib/node/**", tokens)
    bed_pub = bed.declare_publisher("testbed/bed1/sensor/nB")
    assert matched(bed_pub)
    fake = bed.liveliness().declare_token("ordervib/node/fake")
    bed_pub.put(b"control")  # sent after the fake token, on the same link
    assert tokens.wait_for("testbed/bed1/sensor/nB", b"control")

    real_key = f"ordervib/node/{node.zid()}"
    real = node.liveliness().declare_token(real_key)
    assert tokens.wait_for(real_key, b"")
    assert "ordervib/node/fake" not in tokens.keys()
    # a liveliness query (a dashboard's list of live nodes) names the node only
    deadline, replies = time.monotonic() + WAIT, []
    while not replies and time.monotonic() < deadline:  # asked again: a loaded machine may miss one
        replies = [str(r.ok.key_expr) for r in dash.liveliness().get("ordervib/node/**", timeout=WAIT)
                   if r.ok is not None]
    assert replies == [real_key]
    fake.undeclare()
    real.undeclare()
