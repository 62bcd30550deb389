"""Issue 31, items 5 and 6 (findings 7 and 9): a model bundle, its kept training runs and the
engine-state file are untrusted input. Every bad file is one line naming the file and the
field, exit status 2, never a traceback, a hang or a node that fails (or goes quiet) later;
engine-state save failures show. Each test here failed on the code before the fix."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import shutil
import signal
import stat
import struct
import subprocess
import threading
import time
import tracemalloc
import zipfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import orjson
import pytest

from node.cli import main
from node.contract.errors import OrdervibError
from node.contract.schedule import load_schedule
from node.models.bundle import Bundle, load_model, save_bundle
from node.models.config import RuntimeConfig
from node.models.ocmodel import InputScaling, RegressionModel
from node.models.result import Calibration, OCResult


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-run recording (nB, yB, tF) and its schedule beside it."""
    d = tmp_path_factory.mktemp("rec")
    assert main(["simulate", "--runs", "1", "--plateau-scale", "0.05", "--channels", "nB,yB,tF",
                 "--quiet", "--out", str(d / "one.mcap")]) == 0
    return d / "one.mcap"


@pytest.fixture(scope="module")
def good(rec: Path) -> Path:
    """A bundle built here: per OC of the recording's schedule, a Lasso model yB = f(nB)."""
    schedule = load_schedule(rec.with_suffix(".schedule.toml"))
    model = RegressionModel({"alpha": 1.0}, InputScaling(np.array([4000.0]), np.array([1000.0])),
                            coef=np.array([0.5]), intercept=2.0)
    ocs = [OCResult(oc.name, model, ["nB"], {}, 8, 0.1, 0.1, Calibration(1.0, 1e9))
           for oc in schedule.ocs]
    out = save_bundle(Bundle("lasso", "yB", schedule, ocs), rec.parent / "good")
    assert load_model(out).targets == ["yB"]
    return out


def _variant(good: Path, name: str, edit: Callable[[dict], str] | None = None,
             arrays: bytes | None = None) -> Path:
    """A copy of ``good`` with its manifest rewritten by ``edit`` and/or other arrays (the
    manifest's arrays_sha256 rewritten to match them: the hash is no defence)."""
    d = good.parent / name
    shutil.rmtree(d, ignore_errors=True)
    shutil.copytree(good, d)
    manifest = json.loads((d / "manifest.json").read_text())
    if arrays is not None:
        (d / "arrays.npz").write_bytes(arrays)
        manifest["arrays_sha256"] = hashlib.sha256(arrays).hexdigest()
    (d / "manifest.json").write_text(edit(manifest) if edit else json.dumps(manifest))
    return d


def _zip(members: list[tuple[str, bytes, int, int, int]]) -> bytes:
    """An archive written by hand from (name, stored bytes, method, crc32, uncompressed size):
    zipfile cannot store data compressed elsewhere (the 1 GiB member below)."""
    out, central = io.BytesIO(), io.BytesIO()
    for name, data, method, crc, size in members:
        offset, raw = out.tell(), name.encode()
        out.write(struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 0x21, crc, len(data),
                              size, len(raw), 0) + raw + data)
        central.write(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 0x21, crc,
                                  len(data), size, len(raw), 0, 0, 0, 0, 0, offset) + raw)
    n, start = len(members), out.tell()
    out.write(central.getvalue())
    out.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, n, n, len(central.getvalue()), start, 0))
    return out.getvalue()


def _members(npz: bytes) -> list[tuple[str, bytes, int, int, int]]:
    with zipfile.ZipFile(io.BytesIO(npz)) as z:
        return [(i.filename, z.read(i), 0, i.CRC, i.file_size) for i in z.infolist()]


def _npy_header(descr: str, shape: tuple[int, ...]) -> bytes:
    text = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}"
    text += " " * (127 - 10 - len(text)) + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode()


def _gigabyte_of_zeros(name: str) -> tuple[str, bytes, int, int, int]:
    """A member of 1 GiB of float64 zeros, deflated to about 1 MB (made without deflating 1 GiB:
    after a full flush the same input deflates to the same bytes)."""
    header, chunk = _npy_header("<f8", ((1 << 30) // 8,)), bytes(1 << 20)
    co = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = co.compress(header) + co.flush(zlib.Z_FULL_FLUSH)
    block = co.compress(chunk) + co.flush(zlib.Z_FULL_FLUSH)
    assert co.compress(chunk) + co.flush(zlib.Z_FULL_FLUSH) == block
    data = first + block * 1024 + co.flush()
    crc = zlib.crc32(header)
    for _ in range(1024):
        crc = zlib.crc32(chunk, crc)
    return name, data, 8, crc, len(header) + (1 << 30)


@pytest.fixture(scope="module")
def bad(good: Path) -> dict[str, tuple[Path, list[str]]]:
    """Each finding's bundle, with the words its one line must hold (besides the bundle's path)."""
    npz = (good / "arrays.npz").read_bytes()
    members = _members(npz)
    first = members[0][0]  # e.g. "OC2a/u_mean.npy": one value
    big = first.split("/")[0] + "/big.npy"  # a name the manifest accounts for (that OC's)

    def first_header(header: bytes) -> bytes:  # the first array's header replaced, its data kept
        return _zip([(n, d, m, c, s) if n != first else
                     (n, header + d[128:], m, zlib.crc32(header + d[128:]), s)
                     for n, d, m, c, s in members])

    def runtime(key: str, value: float) -> Callable[[dict], str]:
        return lambda m: json.dumps({**m, "runtime": {**m["runtime"], key: value}})

    def residual(key: str, value: object) -> Callable[[dict], str]:
        def edit(m: dict) -> str:
            oc = next(d for d in m["ocs"] if d["residual"] is not None)
            oc["residual"][key] = value
            return json.dumps(m)
        return edit

    def digits(m: dict) -> str:
        m["ocs"][0]["n_runs"] = 0
        return json.dumps(m).replace('"n_runs": 0', '"n_runs": ' + "9" * 5000, 1)

    def deep(m: dict) -> str:
        m["training"] = {"recordings": "DEEP"}
        return json.dumps(m).replace('"DEEP"', "[" * 100_000 + "]" * 100_000)

    return {
        "5000-digit integer": (_variant(good, "digits", digits), ["n_runs", "5000 digits"]),
        "deep nesting": (_variant(good, "deep", deep), ["recordings", "nested deeper than"]),
        "truncated npz": (_variant(good, "truncated", arrays=npz[: len(npz) // 2]),
                          ["arrays.npz", "truncated"]),
        "2**40 elements": (_variant(good, "claims", arrays=first_header(_npy_header("<f8", (1 << 40,)))),
                           [first, "1099511627776 elements"]),
        "unknown 1 GiB member": (_variant(good, "unknown", arrays=_zip(
            [*members, _gigabyte_of_zeros("junk.npy")])), ["junk.npy", "not one expected"]),
        "known name, 1 GiB": (_variant(good, "big", arrays=_zip(
            [*members, _gigabyte_of_zeros(big)])), [big, "bytes or more uncompressed"]),
        "integer array": (_variant(good, "int", arrays=first_header(_npy_header("<i8", (1,)))),
                          [first, "<i8", "float64"]),
        "history_s = 1e300": (_variant(good, "history", runtime("history_s", 1e300)),
                              ["runtime.history_s", "1e+300", "(0, 600] s"]),
        "align_wait_s = 1e300": (_variant(good, "align", runtime("align_wait_s", 1e300)),
                                 ["runtime.align_wait_s", "1e+300", "[0, 10] s"]),
        "sigma = 0": (_variant(good, "sigma", residual("sigma", 0.0)), ["residual.sigma", "positive"]),
        "threshold = -3": (_variant(good, "threshold", residual("threshold", -3.0)),
                           ["residual.threshold", "-3.0"]),
        "ewma_alpha = 7": (_variant(good, "alpha", residual("ewma_alpha", 7)),
                           ["residual.ewma_alpha", "(0, 1]"]),
        "persist = 1e12": (_variant(good, "persist", residual("persist", 1e12)),
                           ["residual.persist", "24000"]),
        "cv_peaks of strings": (_variant(good, "peaks", residual("cv_peaks", ["x"])), ["residual.cv_peaks"]),
    }


FINDINGS = ["5000-digit integer", "deep nesting", "truncated npz", "2**40 elements",
            "unknown 1 GiB member", "known name, 1 GiB", "integer array", "history_s = 1e300",
            "align_wait_s = 1e300", "sigma = 0", "threshold = -3", "ewma_alpha = 7", "persist = 1e12",
            "cv_peaks of strings"]


def _one_line(err: str, *words: str) -> str:
    err = err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ordervib") and "Traceback" not in err, err
    assert all(w in err for w in words), (words, err)
    return err


@pytest.mark.parametrize("finding", FINDINGS)
def test_a_bad_bundle_is_one_line_naming_the_bundle_and_the_field(bad, finding: str) -> None:
    path, words = bad[finding]
    tracemalloc.start()
    try:
        with pytest.raises(OrdervibError) as info:
            load_model(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    assert all(w in message for w in words), (words, message)
    assert peak < 64 << 20  # nothing large was decompressed (before: 1.1 GB for 1 GiB)


@pytest.mark.parametrize("finding", FINDINGS)
def test_run_replay_and_evaluate_refuse_a_bad_bundle_with_exit_2(
        bad, rec: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], finding: str) -> None:
    path, words = bad[finding]
    out = tmp_path / "node.mcap"
    for argv in (["run", "--model", str(path), "--record", str(out), "--duration", "1"],
                 ["replay", str(rec), "--model", str(path), "--quiet"],
                 ["evaluate", str(path), str(rec), "--quiet"]):
        assert main(argv) == 2, argv
        _one_line(capsys.readouterr().err, f"ordervib {argv[0]}:", str(path), *words)
        assert not out.exists()


def test_every_setting_has_a_range_holding_its_default() -> None:
    from node.models.config import RANGES
    defaults = RuntimeConfig().to_dict()
    assert set(RANGES) == set(defaults)
    for name, value in defaults.items():
        RANGES[name].check(name, value)
    for name, bad in (("history_s", 0), ("run_curve_bin", 0), ("detector_off_fraction", 1),
                      ("step_noise_s", 0), ("align_wait_s", float("nan")), ("history_cooling", 1e12)):
        with pytest.raises(ValueError, match=f"runtime.{name} = "):
            RuntimeConfig(**{name: bad})


def test_a_format_1_bundle_s_history_is_bounded_too(good: Path) -> None:
    def v1(m: dict) -> str:
        del m["runtime"]
        return json.dumps({**m, "format_version": 1, "history_s": 1e300})

    with pytest.raises(OrdervibError, match=r"v1: runtime\.history_s = 1e\+300 is outside"):
        load_model(_variant(good, "v1", v1))


# -- the kept training runs (train --update reads them): bounded the same way
def _kept(tmp_path: Path) -> Path:
    from node.training.kept_runs import save_kept_runs
    from node.training.runs import Run
    t = np.arange(0.0, 10.0, 0.025)
    runs = [Run(t + 100 * i, np.column_stack([t, 2 * t]), ("nB", "yB"), "b", None) for i in range(2)]
    save_kept_runs(runs, tmp_path, {"method": "lasso"}, [{"path": "x.mcap", "sha256": "0"}])
    return tmp_path


def test_damaged_kept_runs_are_one_line(tmp_path: Path) -> None:
    from node.training.kept_runs import RUNS_ARRAYS, RUNS_META, load_kept_runs
    folder = _kept(tmp_path)
    runs, _, _ = load_kept_runs(folder)
    assert [r.data.shape for r in runs] == [(400, 2)] * 2
    meta, npz = (folder / RUNS_META).read_text(), (folder / RUNS_ARRAYS).read_bytes()
    (folder / RUNS_META).write_text(meta.replace('"method": "lasso"', '"method": ' + "7" * 5000))
    with pytest.raises(OrdervibError, match="training-runs.json.*'method'.*5000 digits"):
        load_kept_runs(folder)
    (folder / RUNS_META).write_text(meta)
    members = _members(npz)
    for name, arrays, words in (
            ("junk", _zip([*members, _gigabyte_of_zeros("junk.npy")]), "'junk.npy' is not one expected"),
            ("wide", _zip([*members[:-1], ("data1.npy", _npy_header("<f8", (1, 3)) + bytes(24), 0,
                                           zlib.crc32(_npy_header("<f8", (1, 3)) + bytes(24)), 152)]),
             "'data1.npy': shape (1, 3) does not fit run 1's 2 channels")):
        (folder / RUNS_ARRAYS).write_bytes(arrays)
        with pytest.raises(OrdervibError) as info:
            load_kept_runs(folder)
        assert words in str(info.value) and "\n" not in str(info.value), (name, info.value)


# -- the engine-state file
def test_a_replaced_engine_state_keeps_its_mode(tmp_path: Path) -> None:
    from node.edges.engine_file import load_engine_states, save_engine_states
    from node.runtime.history import EngineState
    path = tmp_path / "engine.json"
    for mode in (0o444, 0o640):
        save_engine_states(path, {"b1": EngineState()})
        os.chmod(path, mode)
        states = {"b1": EngineState(1.7e9, 5e4, 0.5, 90.0, 1.9e4)}
        save_engine_states(path, states)
        assert load_engine_states(path) == states
        assert stat.S_IMODE(path.stat().st_mode) == mode  # before: 0o644 (the umask's)


@contextlib.contextmanager
def _fifo(path: Path) -> Iterator[Path]:
    """A FIFO; should a reader wait on it (the code before the fix), a writer comes after a
    while and closes at once, so that the test fails instead of hanging."""
    os.mkfifo(path)

    def unblock() -> None:
        with contextlib.suppress(OSError):
            os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))

    timer = threading.Timer(20.0, unblock)
    timer.start()
    try:
        yield path
    finally:
        timer.cancel()


def test_a_fifo_or_device_engine_state_is_refused_at_once(
        good: Path, rec: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from node.edges.engine_file import load_engine_states, save_engine_states
    out = tmp_path / "node.mcap"
    with _fifo(tmp_path / "engine.json") as fifo:
        for argv in (["run", "--model", str(good), "--record", str(out), "--engine-state", str(fifo),
                      "--duration", "1"],
                     ["replay", str(rec), "--model", str(good), "--engine-state", str(fifo), "--quiet"]):
            assert main(argv) == 2
            _one_line(capsys.readouterr().err, str(fifo), "not a regular file (a FIFO)")
        assert not out.exists()
        with pytest.raises(OSError, match="a FIFO, not a regular file"):
            save_engine_states(fifo, {})
        assert stat.S_ISFIFO(fifo.stat().st_mode)  # before: replaced by a file
    with pytest.raises(OrdervibError, match="not a regular file .a character device."):
        load_engine_states("/dev/null")  # before: read as empty, "not valid JSON"


def _chattr(flag: str, path: Path) -> bool:
    try:
        return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0
    except OSError:
        return False


def test_an_engine_state_that_cannot_be_replaced_stops_run_before_it_starts(
        good: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from node.edges.engine_file import save_engine_states
    path = tmp_path / "engine.json"
    save_engine_states(path, {})
    before = path.read_bytes()
    if not _chattr("+i", path):
        pytest.skip("chattr +i is not allowed here")
    try:
        out = tmp_path / "node.mcap"
        assert main(["run", "--model", str(good), "--record", str(out), "--engine-state", str(path),
                     "--duration", "0.5"]) == 2  # before: exit 0, one log line
        _one_line(capsys.readouterr().err, "ordervib run:", str(path), "cannot be saved")
        assert not out.exists()
    finally:
        _chattr("-i", path)
    assert path.read_bytes() == before


def _refuse_saves(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every save of the running node fails as on an immutable file (EPERM)."""
    def save(path: object, states: object) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted", str(path))
    monkeypatch.setattr("node.live.node.save_engine_states", save)


def test_a_failing_engine_state_save_shows_in_health(good: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from node.live.node import LiveNode
    from node.mcap import RecordingWriter
    node = LiveNode(load_model(good), RecordingWriter(io.BytesIO()), engine_file=str(tmp_path / "e.json"))
    node.core.handle("testbed/b1/sensor/nB", orjson.dumps({"t": 1.0, "v": 100.0}))
    with monkeypatch.context() as m:
        _refuse_saves(m)
        node._save_engines()
        assert node.health("b1", time.time())["engine_state"] is False  # before: not in health
    node._save_engines()  # the next save works: the alarm clears
    assert node.health("b1", time.time())["engine_state"] is True
    assert (tmp_path / "e.json").exists()
    none = LiveNode(load_model(good), RecordingWriter(io.BytesIO()))
    none.core.handle("testbed/b1/sensor/nB", orjson.dumps({"t": 1.0, "v": 100.0}))
    assert none.health("b1", time.time())["engine_state"] is None  # no file kept


def test_a_failing_engine_state_save_makes_run_exit_non_zero(
        good: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from harness.live import free_port
    _refuse_saves(monkeypatch)
    path, out = tmp_path / "engine.json", tmp_path / "node.mcap"
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        code = main(["run", "--model", str(good), "--record", str(out), "--engine-state", str(path),
                     "--listen", f"tcp/127.0.0.1:{free_port()}", "--duration", "0.5", "--quiet"])
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2, lines  # before: 0
    assert "Operation not permitted" in lines[0]  # logged once, at once
    _one_line(lines[-1], "ordervib run: engine state", str(path), "not saved", "Operation not permitted")
    assert out.exists()  # the recording was finished all the same
