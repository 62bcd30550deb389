"""Several targets in one model: training, the format-3 folder, the node's monitor/<target> each."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import orjson
import pytest

from node.cli import main
from node.contract import ORDER_CHANNELS, is_monitor_key, monitor_key, oc_key, transient_key
from node.contract.errors import OrdervibError
from node.mcap import read_payloads
from node.models.bundle import Model, load_bundle, load_model, save_model
from node.models.config import RuntimeConfig
from replay.offline import replay

ROOT = Path(__file__).resolve().parents[1]
CHANNELS = ["--channels", "nB,yA,yB,yC,tF", "--plateau-scale", "0.05", "--quiet"]
LASSO = ["--method", "lasso", "--inputs", "nB,tF", "--quiet", "--workers", "1"]


def _train(d: Path, out: str, *extra: str) -> list[str]:
    return ["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"),
            "--out", str(d / out), *LASSO, *extra]


@pytest.fixture(scope="module")
def camp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """train.mcap (2 short runs of yA, yB, yC), test.mcap (the next run), model ``all`` (the
    default targets) and ``yA``, ``yB``, ``yC`` (each alone, the same options)."""
    d = tmp_path_factory.mktemp("targets")
    assert main(["simulate", "--runs", "2", "--seed", "3", "--out", str(d / "train.mcap"), *CHANNELS]) == 0
    assert main(["simulate", "--runs", "3", "--skip", "2", "--seed", "3", "--out", str(d / "test.mcap"),
                 *CHANNELS]) == 0
    assert main(_train(d, "all")) == 0
    for t in ORDER_CHANNELS:
        assert main(_train(d, t, "--target", t)) == 0
    return d


def _monitor(path: Path) -> dict[str, list[bytes]]:
    return {k: v for k, v in read_payloads(str(path)).items() if is_monitor_key(k)}


def test_default_is_every_tracked_order_in_one_format_3_folder(camp: Path) -> None:
    manifest = json.loads((camp / "all" / "manifest.json").read_text())
    assert manifest["format_version"] == 3 and manifest["targets"] == list(ORDER_CHANNELS)
    model = load_model(camp / "all")
    assert model.targets == list(ORDER_CHANNELS)
    for t in ORDER_CHANNELS:  # each target trained as it is alone: the same bundle
        alone = load_bundle(camp / t)
        assert (camp / "all" / t / "arrays.npz").read_bytes() == (camp / t / "arrays.npz").read_bytes()
        assert model[t].ocs[0].inputs == alone.ocs[0].inputs and model[t].checks == alone.checks
    with pytest.raises(OrdervibError, match="holds 3 targets"):
        load_bundle(camp / "all")


def test_each_target_publishes_what_it_does_alone_and_workers_agree(camp: Path, tmp_path: Path) -> None:
    model = load_model(camp / "all")
    outs = []
    for w in (0, 1):
        outs.append(tmp_path / f"all{w}.mcap")
        replay(str(camp / "test.mcap"), model, str(outs[-1]), workers=w)
    assert outs[0].read_bytes() == outs[1].read_bytes()
    together = _monitor(outs[0])
    bed = next(iter(together)).split("/")[1]
    assert set(together) == {oc_key(bed), transient_key(bed),
                             *(monitor_key(bed, t) for t in ORDER_CHANNELS)}
    for t in ORDER_CHANNELS:
        replay(str(camp / "test.mcap"), load_model(camp / t), str(tmp_path / f"{t}.mcap"), workers=0)
        alone = _monitor(tmp_path / f"{t}.mcap")
        assert set(alone) == {oc_key(bed), transient_key(bed), monitor_key(bed, t)}
        assert together[monitor_key(bed, t)] == alone[monitor_key(bed, t)]  # byte for byte
        assert together[oc_key(bed)] == alone[oc_key(bed)]  # once per bed, as alone
        mine = [m for m in together[transient_key(bed)] if orjson.loads(m)["target"] == t]
        assert mine and mine == alone[transient_key(bed)]  # each target's transitions, as alone
    assert len(together[monitor_key(bed, "yA")]) > 100


def test_train_prints_a_table_per_target_and_evaluate_too(camp: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(_train(camp, str(tmp_path / "ca"), "--target", "yC,yA")) == 0
    text = capsys.readouterr().out
    assert text.index("target yC:") < text.index("target yA:") and text.count("mean cross-validated") == 2
    assert load_model(tmp_path / "ca").targets == ["yC", "yA"]
    assert main(["evaluate", str(tmp_path / "ca"), str(camp / "test.mcap"), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert text.count("mean held-out eps_td") == 2 and text.count("node alarms") == 1
    assert all((tmp_path / "ca" / f"evaluation-{t}.png").exists() for t in ("yC", "yA"))


@pytest.mark.parametrize("targets, words", [("yB,yQ", ["--target yQ", "missing"]),
                                            ("yB,yB", ["repeats yB"]), (",", ["names no channel"])])
def test_a_bad_target_is_one_line(camp: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                  targets: str, words: list[str]) -> None:
    assert main(_train(camp, str(tmp_path / "m"), "--target", targets)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ordervib train") and "Traceback" not in err
    assert all(w in err for w in words), err
    assert not (tmp_path / "m").exists()


def test_one_target_is_format_2_and_formats_1_2_load_as_one_target(camp: Path, tmp_path: Path) -> None:
    manifest = json.loads((camp / "yB" / "manifest.json").read_text())
    assert manifest["format_version"] == 2 and manifest["target"] == "yB"
    one = load_model(camp / "yB")
    assert one.targets == ["yB"] and one["yB"].ocs[0].name == load_bundle(camp / "yB").ocs[0].name
    v1 = tmp_path / "v1"
    shutil.copytree(camp / "yB", v1)
    manifest.update(format_version=1, history_s=60.0)
    del manifest["runtime"]
    (v1 / "manifest.json").write_text(json.dumps(manifest))
    assert load_model(v1).targets == ["yB"] and load_model(v1).config.align_wait_s == 0.1
    save_model(one, tmp_path / "again")  # a one-target Model is written as format 2
    assert json.loads((tmp_path / "again" / "manifest.json").read_text())["format_version"] == 2


def test_a_malformed_format_3_folder_is_one_line(camp: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad"
    shutil.copytree(camp / "all", bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    for targets, match in ((["../yB"], "targets must be"), ([], "targets must be"),
                           (["yB", "yZ"], "model bundle not found"), (["yA", "yA"], "repeated")):
        (bad / "manifest.json").write_text(json.dumps({**manifest, "targets": targets}))
        with pytest.raises(OrdervibError, match=match) as exc:
            load_model(bad)
        assert "\n" not in str(exc.value)
    (bad / "manifest.json").write_text(json.dumps({**manifest, "targets": ["yB", "yA"]}))
    shutil.rmtree(bad / "yA")
    shutil.copytree(camp / "yC", bad / "yA")  # holds yC
    with pytest.raises(OrdervibError, match="holds target 'yC'"):
        load_model(bad)
    other = dataclasses.replace(load_bundle(camp / "yB"), config=RuntimeConfig(align_wait_s=0.1))
    with pytest.raises(ValueError, match="differ"):  # the targets share schedule and settings
        Model((load_bundle(camp / "yA"), other))


@pytest.mark.skipif(not os.environ.get("ORDERVIB_REFERENCE"),
                    reason="ORDERVIB_REFERENCE=<checkout of the reference code> compares with it")
def test_one_target_model_gives_the_reference_codes_messages(tmp_path: Path) -> None:
    """One target, one bundle: trained and replayed by this code and by the reference checkout's
    (``python -m node.cli`` run there), the monitor and oc messages are the same bytes."""
    ref = Path(os.environ["ORDERVIB_REFERENCE"])
    rec, sched = ROOT / "recordings" / "engine1_runs.mcap", ROOT / "recordings" / "engine1_runs.schedule.toml"
    argv = ["train", str(rec), "--schedule", str(sched), "--method", "lasso", "--inputs", "nB,tF",
            "--target", "yB", "--quiet", "--workers", "1"]
    outs = {}
    for name, cwd in (("ref", ref), ("ours", ROOT)):
        model, out = tmp_path / f"m-{name}", tmp_path / f"{name}.mcap"
        play = ["replay", str(rec), "--model", str(model), "--out", str(out), "--quiet", "--workers", "0"]
        for cmd in ([*argv, "--out", str(model)], play):
            subprocess.run([sys.executable, "-m", "node.cli", *cmd], cwd=cwd, check=True,
                           stdout=subprocess.DEVNULL)
        outs[name] = _monitor(out)
    assert outs["ours"] == outs["ref"] and len(outs["ours"]) == 2


def test_targets_of_a_bed_share_one_oc_detector_and_a_foreign_one_is_refused() -> None:
    """A bed's pipelines step one OC detector (the first target's, once per sample): its OC and
    phase in every target's message; a detector of another schedule is refused."""
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle
    from node.runtime.core import NodeCore
    from node.runtime.pipeline import MonitorPipeline

    sched = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))
    core = NodeCore(Model((Bundle("wdmd", "yA", sched, []), Bundle("wdmd", "yB", sched, []))))
    out = []
    for k in range(1200):  # 15 s at 4000 rpm, then 15 s at 6000
        t = 100.0 + k / 40
        speed = 4000.0 if k < 600 else 6000.0
        for ch, v in (("nB", speed), ("yA", 1.0), ("yB", 2.0)):
            out += core.handle(f"testbed/b1/sensor/{ch}", json.dumps({"t": t, "v": v}).encode())
    first, second = core.beds["b1"].pipelines
    assert second.detector is first.detector
    by_target = {t: [(m["t"], m["oc"], m["phase"]) for k, m in out if k == monitor_key("b1", t)]
                 for t in ("yA", "yB")}
    assert by_target["yA"] == by_target["yB"] and len(by_target["yA"]) > 1000
    assert {oc for _, oc, phase in by_target["yA"] if phase == "steady"} == {"A", "B"}
    other = Schedule((OperatingCondition("A", 4100.0),))
    with pytest.raises(ValueError, match="shared OC detector"):
        MonitorPipeline(Bundle("wdmd", "yC", other, []), detector=first.detector)
