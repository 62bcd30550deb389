"""The compiled per-sample modules (``node.native``): when they run, and that they give the pure
Python modules' outputs to the bit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from node import native
from node.mcap import iter_messages_fast

ROOT = Path(__file__).resolve().parents[1]


def fake_project(root: Path, compiled: bool) -> tuple[str, ...]:
    """root/pkg/mod.py (``VALUE = 'source'``), with a stand-in compiled file beside it if asked."""
    (root / "pkg").mkdir()
    (root / "pkg" / "__init__.py").write_text("")
    (root / "pkg" / "mod.py").write_text("VALUE = 'source'\n")
    if compiled:
        (root / "pkg" / f"mod{native.importlib.machinery.EXTENSION_SUFFIXES[0]}").write_bytes(b"")
    return ("pkg.mod",)


def test_the_compiled_modules_run_only_when_built_from_the_sources_as_they_are(tmp_path: Path) -> None:
    stamp = tmp_path / "stamp.json"
    mods = fake_project(tmp_path, compiled=False)
    assert native.judge(mods, tmp_path, stamp, env={}) == "absent"
    (tmp_path / "pkg" / f"mod{native.importlib.machinery.EXTENSION_SUFFIXES[0]}").write_bytes(b"")
    assert native.judge(mods, tmp_path, stamp, env={}) == "stale"  # no stamp
    stamp.write_text(native.json.dumps({"version": native.STAMP_VERSION, "modules": list(mods),
                                        "sources": native.digest(mods, tmp_path)}))
    assert native.judge(mods, tmp_path, stamp, env={}) == "compiled"
    assert native.judge(mods, tmp_path, stamp, env={native.PURE_ENV: "1"}) == "off"
    assert native.judge(mods, tmp_path, stamp, env={native.PURE_ENV: "0"}) == "compiled"
    assert native.judge(("pkg.mod", "pkg.other"), tmp_path, stamp, env={}) == "stale"  # another list
    (tmp_path / "pkg" / "mod.py").write_text("VALUE = 'edited'\n")  # a source changed since the build
    assert native.judge(mods, tmp_path, stamp, env={}) == "stale"
    stamp.write_text("{not json")
    assert native.judge(mods, tmp_path, stamp, env={}) == "stale"
    assert native.clean(mods, tmp_path, stamp) == 2  # the compiled file and the stamp
    assert native.judge(mods, tmp_path, stamp, env={}) == "absent"
    assert (tmp_path / "pkg" / "mod.py").exists()


def test_the_pure_finder_loads_the_source_whatever_lies_beside_it(tmp_path: Path) -> None:
    mods = fake_project(tmp_path, compiled=True)  # an empty file: importing it would fail
    finder = native.PureFinder(mods, tmp_path)
    spec = finder.find_spec("pkg.mod")
    assert spec is not None and spec.origin == str(tmp_path / "pkg" / "mod.py")
    assert finder.find_spec("pkg.other") is None  # not its business
    module = native.importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(module)
    assert module.VALUE == "source"


def run(args: list[str], pure: bool, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != native.PURE_ENV}
    if pure:
        env[native.PURE_ENV] = "1"
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A default three-target model trained on 2 short simulated runs (averages of anchored, vector
    and influence curves, WDMD members, settling) and the next run (test.mcap)."""
    from node.cli import main
    d = tmp_path_factory.mktemp("native")
    common = ["--seed", "7", "--plateau-scale", "0.08", "--quiet"]
    assert main(["simulate", "--runs", "3", "--skip", "2", "--out", str(d / "test.mcap"), *common]) == 0
    assert main(["simulate", "--runs", "2", "--out", str(d / "train.mcap"), *common]) == 0
    assert main(["train", str(d / "train.mcap"), "--schedule", str(d / "train.schedule.toml"), "--out",
                 str(d / "m"), "--quiet", "--workers", "1"]) == 0
    return d


def test_the_compiled_modules_doctests_pass_from_their_sources() -> None:
    """Compiled, the session leaves these doctests out (``conftest.py``): here they run."""
    files = [str(native.source(m)) for m in native.COMPILED]
    r = run(["-m", "pytest", "-q", "-o", "addopts=", "--doctest-modules", "-p", "no:cacheprovider", *files],
            pure=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout[-2000:]
    passed = r.stdout.strip().splitlines()[-1]
    assert passed.endswith(" passed") or " passed in " in passed, passed
    assert int(passed.split()[0]) >= 40, passed  # the modules' doctests, not a few


def test_the_compiled_modules_replay_to_the_bit_what_the_pure_ones_do(campaign: Path) -> None:
    state = run(["-c", "from node import native; print(native.state())"], pure=False, cwd=ROOT)
    assert state.stdout.strip() == "compiled", \
        f"the compiled modules do not run ({state.stdout.strip()}): ordervib native build"
    outs = {}
    for pure in (False, True):
        out = campaign / f"replay-{'pure' if pure else 'compiled'}.mcap"
        r = run(["-m", "node.cli", "replay", str(campaign / "test.mcap"), "--model", str(campaign / "m"),
                 "--out", str(out), "--workers", "0", "--quiet"], pure=pure, cwd=ROOT)
        assert r.returncode == 0, r.stderr
        outs[pure] = [(m.topic, m.log_time, m.publish_time, bytes(m.payload))
                      for m in iter_messages_fast(str(out))]
    compiled, pure_ = outs[False], outs[True]
    assert len(compiled) > 1_000 and any("/monitor/yA" in m[0] for m in compiled)
    assert len(compiled) == len(pure_)
    differ = [i for i, (a, b) in enumerate(zip(compiled, pure_, strict=True)) if a != b]
    assert not differ, f"{len(differ)} of {len(compiled)} messages differ, the first: {compiled[differ[0]]}"
