"""Conventions across commands (issue 34): JSON encoding of every published sample, one schema
name per topic kind, Zenoh option errors in one line, --log-level anywhere, results on stdout."""

from __future__ import annotations

import socket
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
    from harness.live import wait_for
    from node.edges.zenoh import open_session, zenoh_config
    from replay.publish import publish_recording

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    encodings: list[str] = []
    session = open_session(zenoh_config([endpoint], None, None))
    sub = session.declare_subscriber("testbed/**", lambda s: encodings.append(str(s.encoding)))
    try:
        sent = publish_recording(str(sim), endpoint, speed=0.0, quiet=True)
        wait_for(lambda: len(encodings) >= sent, 20)
    finally:
        sub.undeclare()
        session.close()
    assert sent > 0 and len(encodings) == sent
    assert set(encodings) == {str(zenoh.Encoding.APPLICATION_JSON)}


@pytest.mark.parametrize("argv, option", [
    (["run", "--model", "no-model", "--record", "REC", "--listen", "nonsense"], "--listen 'nonsense'"),
    (["run", "--model", "no-model", "--record", "REC", "--connect", "tcp/"], "--connect 'tcp/'"),
    (["router", "--listen", "nonsense", "--duration", "1"], "--listen 'nonsense'"),
    (["replay", str(COMMITTED), "--publish", "--connect", "nonsense"], "--connect 'nonsense'"),
    (["view", "--connect", "nonsense", "--duration", "1", "--save", "RRD"], "--connect 'nonsense'"),
])
def test_a_bad_endpoint_is_one_line_naming_the_option(argv: list[str], option: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("zenoh")
    files = {"REC": str(tmp_path / "rec.mcap"), "RRD": str(tmp_path / "view.rrd")}
    argv = [files.get(a, a) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and option in err, err
    assert "Json5Err" not in err and ".rs:" not in err and ".cargo" not in err


@pytest.mark.parametrize("text", ["{mode: ", '{mode: "nope"}', None])
def test_a_bad_zenoh_config_file_is_one_line_naming_the_option(text: str | None, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("zenoh")
    conf = tmp_path / "z.json5"
    if text is not None:
        conf.write_text(text)
    assert main(["router", "--zenoh-config", str(conf), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and f"--zenoh-config {conf}" in err, err
    assert "Message {" not in err and ".rs:" not in err and ".cargo" not in err


def test_an_endpoint_the_session_cannot_open_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("zenoh")
    assert main(["router", "--listen", "tcp/127.0.0.1:notaport", "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "tcp/127.0.0.1:notaport" in err and "--listen" in err, err
    assert ".rs:" not in err and ".cargo" not in err


@pytest.mark.parametrize("before, after", [(["--log-level", "warning"], []), ([], ["--log-level", "warning"]),
                                           (["--log-level", "debug"], ["--log-level", "warning"])])
def test_log_level_is_accepted_before_or_after_the_sub_command(before: list[str], after: list[str],
                                                               tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """After the sub-command it counts too (the later one wins); at warning, no status on stderr."""
    assert main([*before, *SIM, "--out", str(tmp_path / "x.mcap"), *after]) == 0
    assert capsys.readouterr().err == ""


def test_every_sub_command_takes_log_level() -> None:
    from node.cli import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if a.dest == "command")
    for name, p in subs.choices.items():  # type: ignore[union-attr]
        assert "--log-level" in p._option_string_actions, name


def test_a_bad_log_level_after_the_sub_command_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--out", "x.mcap", "--log-level", "loud"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--log-level" in err


@pytest.mark.parametrize("option", [[], ["--log-level", "warning"], ["--quiet"]])
def test_simulate_prints_what_it_wrote_on_stdout(option: list[str], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.mcap"
    assert main([*SIM, "--out", str(out), *option]) == 0
    res = capsys.readouterr()
    assert res.out.startswith("simulate: 1 runs, ") and f"-> {out} " in res.out
    assert len(res.out.splitlines()) == 1
    assert "-> " not in res.err  # the result is not repeated on stderr
    if option:
        assert res.err == ""


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from conftest import small_campaign

    return small_campaign(tmp_path_factory.mktemp("camp"), seed=5)


@pytest.mark.parametrize("option", [[], ["--log-level", "warning"], ["--quiet"]])
def test_replay_model_prints_its_summary_on_stdout(option: list[str], campaign: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.mcap"
    assert main(["replay", str(campaign / "test.mcap"), "--model", str(campaign / "m"), "--out", str(out),
                 "--workers", "0", *option]) == 0
    res = capsys.readouterr()
    lines = res.out.splitlines()
    assert lines[0].startswith("replayed ") and "monitor messages" in lines[0]
    assert lines[1].startswith("  bed1: ") and "alarm samples" in lines[1]
    assert lines[-1] == f"wrote {out}"
    assert "replayed " not in res.err and "wrote " not in res.err
    if option:
        assert res.err == ""


def _schema_names(path: Path) -> dict[str, set[str]]:
    """Topic kind -> the schema names a recording's channels of that kind carry."""
    from mcap.reader import make_reader

    from node.contract.keys import topic_kind

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    out: dict[str, set[str]] = {}
    for ch in summary.channels.values():
        out.setdefault(topic_kind(ch.topic).value, set()).add(summary.schemas[ch.schema_id].name)
    return out


def test_a_fresh_simulation_and_a_node_recording_name_the_sensor_schema_alike(
        sim: Path, campaign: Path, tmp_path: Path) -> None:
    from node.contract.keys import TopicKind
    from node.mcap import SCHEMA_NAMES

    node_rec = tmp_path / "node.mcap"
    assert main(["replay", str(campaign / "test.mcap"), "--model", str(campaign / "m"),
                 "--out", str(node_rec), "--workers", "0", "--quiet"]) == 0
    simulated, recorded = _schema_names(sim), _schema_names(node_rec)
    assert simulated["sensor"] == recorded["sensor"] == {SCHEMA_NAMES[TopicKind.SENSOR]}
    for kind, names in recorded.items():  # one name per kind, the one SCHEMA_NAMES gives
        assert names == {SCHEMA_NAMES[TopicKind(kind)]}, kind


def test_readers_accept_the_old_spelling_and_a_copy_writes_the_one_name(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Recordings from before session 13 say ordervib.Sensor: they read as sensor recordings;
    the committed ones were rewritten (recover, session 16) and say the one name, as a copy the
    project writes does."""
    from node.contract.keys import TopicKind
    from node.mcap import SCHEMA_NAMES, iter_messages, schema_kind

    assert _schema_names(COMMITTED)["sensor"] == {SCHEMA_NAMES[TopicKind.SENSOR]}
    assert schema_kind("ordervib.Sensor") == schema_kind(SCHEMA_NAMES[TopicKind.SENSOR]) == TopicKind.SENSOR
    assert all(schema_kind(name) == kind for kind, name in SCHEMA_NAMES.items())
    assert schema_kind("something.else") is None
    first = next(iter(iter_messages(str(COMMITTED))))
    assert first.topic.startswith("testbed/")
    out = tmp_path / "copy.mcap"
    assert main(["recover", str(COMMITTED), "--out", str(out)]) == 0
    assert _schema_names(out) == {"sensor": {SCHEMA_NAMES[TopicKind.SENSOR]}}


def test_only_the_product_is_installed() -> None:
    """pip installs node, replay and simulator (the ordervib command needs them); the benchmarks
    and the harness run from the repository (issue 34 item 8)."""
    import importlib.metadata

    top = set((importlib.metadata.distribution("ordervib").read_text("top_level.txt") or "").split())
    assert top == {"node", "replay", "simulator"}
