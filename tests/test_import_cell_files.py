"""``ordervib import`` on test-cell files as a test cell writes them, made here with asammdf and
npTDMS (not with the project's code): an MDF4 file with channel groups at their own rates and
units, a TDMS file whose channels keep their own start times and rates, a mixed-rate CSV export
(a 10 Hz column blank between its rows of a 100 Hz file). Values and times must survive within
what linear resampling can move them; each bad file or map (cut TDMS and MDF4, a short channel,
a unit the file contradicts, blank cells, a folder as map, a missing channel, a wrong type) ends
in one line, exit 2, no output and an existing output left whole, or with --allow-partial in an
import whose gap is counted in the summary and in the recording's metadata.
"""

from __future__ import annotations

import datetime as dt
import math
import struct
from pathlib import Path

import numpy as np
import orjson
import pytest
from asammdf import MDF, Signal
from mcap.reader import make_reader
from mcap_spec import check_indexed
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from node.cli import main
from node.contract import FS, decode_samples, parse_sensor_key
from node.mcap import read_payloads

START = 1_767_600_000.0  # 2026-01-05T08:00:00Z
DUR = 60.0  # s of each file
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)


def n_b(t: np.ndarray) -> np.ndarray:
    """IP speed, rpm: a ramp with a slow swing (s since START)."""
    return 3000.0 + 20.0 * t + 50.0 * np.sin(2 * np.pi * t / 20.0)


def y_b(t: np.ndarray) -> np.ndarray:
    """IP 1x amplitude, mm/s peak."""
    return 2.0 + 0.5 * np.sin(2 * np.pi * t / 30.0)


def t_a(t: np.ndarray) -> np.ndarray:
    """A temperature, degC: linear (exact under linear interpolation)."""
    return 400.0 + 1.5 * t


def bound(f_hz: float, amp: float, step: float) -> float:
    """Linear interpolation's largest error on amp sin(2 pi f t) sampled every ``step`` s."""
    return amp * (2 * np.pi * f_hz) ** 2 * step**2 / 8.0


# largest error of each channel's resampling from its own rate (+ float64 epoch times: 0.24 us)
TOL = {"nB": lambda step: bound(1 / 20.0, 50.0, step) + 20.0 * 1e-6,
       "yB": lambda step: bound(1 / 30.0, 0.5, step) + 1e-9,
       "tA": lambda step: 1.5 * 1e-6}
TRUE = {"nB": n_b, "yB": y_b, "tA": t_a}


def read_back(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per contract channel: (t s since the epoch, v, NaN for null) of an imported recording."""
    out = {}
    for topic, payloads in read_payloads(path).items():
        parsed = parse_sensor_key(topic)
        assert parsed is not None
        t, v, ok = decode_samples(payloads)
        assert ok.all()
        out[parsed[1]] = (t, v)
    return out


def metadata(path: Path) -> dict[str, str]:
    """The recording's ``ordervib.import`` metadata record (through mcap's own reader)."""
    with open(path, "rb") as f:
        found = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    return found["ordervib.import"]


def check_values(got: dict[str, tuple[np.ndarray, np.ndarray]], steps: dict[str, float],
                 spans: dict[str, tuple[float, float]]) -> None:
    """Every 40 Hz slot of each channel's span (s from START), no null, each value the true
    function within what linear interpolation from the channel's own step can move it."""
    for ch, step in steps.items():
        t, v = got[ch]
        a, b = spans[ch]
        want = np.arange(math.ceil((START + a) * FS), math.floor((START + b) * FS) + 1) / FS
        assert np.array_equal(t, want), ch
        assert not np.isnan(v).any(), ch
        err = np.abs(v - TRUE[ch](t - START)).max()
        assert err <= TOL[ch](step), (ch, err, TOL[ch](step))


def run(argv: list[str]) -> int:
    return main(["import", *argv])


# -- the files


def mdf4(path: Path, short_yb: float | None = None) -> Path:
    """nB at 100 Hz in rad/s, yB at 10 Hz in in/s (``short_yb``: ending that many s early), tA
    at 1 Hz in degF: three channel groups, times relative to the header's start."""
    mdf = MDF(version="4.10")
    mdf.header.start_time = dt.datetime.fromtimestamp(START, tz=dt.UTC)
    fast, mid, slow = (np.arange(0, DUR + 1e-9, step) for step in (0.01, 0.1, 1.0))
    if short_yb is not None:
        mid = mid[mid <= DUR - short_yb + 1e-9]
    mdf.append([Signal(n_b(fast) / RPM_PER_RAD_S, fast, name="IP_SPEED", unit="rad/s")])
    mdf.append([Signal(y_b(mid) / 25.4, mid, name="VIB_IP_1X", unit="in/s")])
    mdf.append([Signal(t_a(slow) * 9 / 5 + 32, slow, name="T_OIL", unit="degF")])
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def tdms(path: Path, segments: int = 1) -> Path:
    """nB at 100 Hz (rpm) from START + 0.0137 s, yB at 10 Hz (mm/s) from START + 0.25 s: each
    channel its own wf_start_time and wf_increment, written in ``segments`` segments."""
    def wf(t0: float, inc: float, unit: str) -> dict:
        return {"wf_start_time": np.datetime64(round((START + t0) * 1e6), "us"), "wf_increment": inc,
                "unit_string": unit}

    nb_t, yb_t = 0.0137 + np.arange(6000) * 0.01, 0.25 + np.arange(600) * 0.1
    with TdmsWriter(path) as w:
        for i in range(segments):
            a, b = 6000 * i // segments, 6000 * (i + 1) // segments
            c, d = 600 * i // segments, 600 * (i + 1) // segments
            w.write_segment([RootObject({}), GroupObject("Engine", {}),
                             ChannelObject("Engine", "IP_SPEED", n_b(nb_t[a:b]), wf(0.0137, 0.01, "rpm")),
                             ChannelObject("Engine", "VIB_IP_1X", y_b(yb_t[c:d]), wf(0.25, 0.1, "mm/s"))])
    return path


def mixed_csv(path: Path, dropouts: bool = False) -> Path:
    """100 Hz rows: nB every row, yB every 10th row (blank between), tA every row; with
    ``dropouts`` tA blank on a few irregular rows."""
    rows = ["time,IP speed [rpm],IP 1x [mm/s],T oil [degC]"]
    for i in range(6000):
        t = i / 100.0
        yb = repr(float(y_b(np.array(t)))) if i % 10 == 4 else ""
        ta = "" if dropouts and i % 997 == 5 else repr(float(t_a(np.array(t))))
        rows.append(f"{START + t!r},{float(n_b(np.array(t)))!r},{yb},{ta}")
    path.write_text("\n".join(rows) + "\n")
    return path


def write_map(path: Path, body: str, time: str = "") -> Path:
    path.write_text(f'bed = "cell7"\n{time}\n{body}')
    return path


MF4_MAP = ('[channels.nB]\nsource = "IP_SPEED"\n[channels.yB]\nsource = "VIB_IP_1X"\n'
           '[channels.tA]\nsource = "T_OIL"\n')
TDMS_MAP = '[channels.nB]\nsource = "IP_SPEED"\n[channels.yB]\nsource = "VIB_IP_1X"\n'
CSV_MAP = ('[channels.nB]\nsource = "IP speed [rpm]"\n[channels.yB]\nsource = "IP 1x [mm/s]"\n'
           '[channels.tA]\nsource = "T oil [degC]"\n')
CSV_TIME = '[time]\ncolumn = "time"\n'


# -- what survives


def test_mdf4_groups_of_their_own_rates_and_units(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Three channel groups (100, 10, 1 Hz; rad/s, in/s, degF): every value on the grid within
    the resampling's bound, the summary a row per channel (source, unit, rate, span, samples),
    the metadata record whole, not partial."""
    out = tmp_path / "o.mcap"
    assert run([str(mdf4(tmp_path / "cell.mf4")), "--map", str(write_map(tmp_path / "m.toml", MF4_MAP)),
                "--out", str(out)]) == 0
    check_indexed(out)
    check_values(read_back(out), {"nB": 0.01, "yB": 0.1, "tA": 1.0},
                 {"nB": (0.0, DUR), "yB": (0.0, DUR), "tA": (0.0, DUR)})
    text = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in text.splitlines()[2:5]}
    assert rows["nB"][1:5] == ["IP_SPEED", "rad/s", "100", "0.0"] and rows["nB"][6:8] == ["60.0", "6001"]
    assert rows["yB"][1:4] == ["VIB_IP_1X", "in/s", "10"] and rows["yB"][7] == "601"
    assert rows["tA"][1:4] == ["T_OIL", "degF", "1"] and rows["tA"][7] == "61"
    meta = metadata(out)
    assert meta["partial"] == "false" and meta["file"] == "cell.mf4" and meta["format"] == "mf4"
    nb = orjson.loads(meta["channel.nB"])
    assert nb["source"] == "IP_SPEED" and nb["unit"] == "rad/s" and nb["rate_hz"] == 100.0
    assert nb["samples"] == nb["declared"] == 6001 and nb["written"] == 2401 and nb["missing_s"] == 0.0


def test_tdms_channels_with_their_own_start_times(tmp_path: Path) -> None:
    """Each TDMS channel on its own clock (wf_start_time, wf_increment): every slot between its
    own first and last sample, the values within the resampling's bound."""
    out = tmp_path / "o.mcap"
    assert run([str(tdms(tmp_path / "cell.tdms", segments=4)), "--map",
                str(write_map(tmp_path / "m.toml", TDMS_MAP)), "--out", str(out), "--quiet"]) == 0
    check_values(read_back(out), {"nB": 0.01, "yB": 0.1},
                 {"nB": (0.0137, 0.0137 + 59.99), "yB": (0.25, 0.25 + 59.9)})


def test_mixed_rate_csv_blank_means_not_sampled(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 10 Hz column blank between its rows of a 100 Hz export: detected (its own rate) and
    resampled from its own samples, no null; irregular blanks stay dropouts (null) unless the
    map says blank = "not-sampled"; blank = "null" writes the blanks as nulls."""
    out = tmp_path / "o.mcap"
    csv = mixed_csv(tmp_path / "cell.csv")
    m = write_map(tmp_path / "m.toml", CSV_MAP, CSV_TIME)
    assert run([str(csv), "--map", str(m), "--out", str(out)]) == 0
    check_values(read_back(out), {"nB": 0.01, "yB": 0.1, "tA": 0.01},
                 {"nB": (0.0, 59.99), "yB": (0.04, 59.94), "tA": (0.0, 59.99)})
    assert "yB: a value every 10 rows (its own rate)" in capsys.readouterr().out
    holes = mixed_csv(tmp_path / "holes.csv", dropouts=True)
    out.unlink()
    assert run([str(holes), "--map", str(tmp_path / "m.toml"), "--out", str(out), "--quiet"]) == 0
    assert np.isnan(read_back(out)["tA"][1]).sum() > 0  # dropouts: null around each
    out.unlink()
    write_map(tmp_path / "m2.toml", CSV_MAP + 'blank = "not-sampled"\n', CSV_TIME)
    assert run([str(holes), "--map", str(tmp_path / "m2.toml"), "--out", str(out), "--quiet"]) == 0
    check_values(read_back(out), {"tA": 0.02}, {"tA": (0.0, 59.99)})
    out.unlink()
    write_map(tmp_path / "m3.toml", CSV_MAP, CSV_TIME + '[csv]\nblank = "null"\n')
    assert run([str(csv), "--map", str(tmp_path / "m3.toml"), "--out", str(out), "--quiet"]) == 0
    assert np.isnan(read_back(out)["yB"][1]).all()


# -- bad files and maps


def fails(capsys: pytest.CaptureFixture[str], argv: list[str], out: Path, words: list[str]) -> str:
    """Exit 2, one line holding every one of ``words``, no output, no temporary file; then the
    same with --force over an existing output, which is left as it was. The line."""
    code = run([*argv, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("ordervib import: "), err
    assert "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
    assert not out.exists()
    out.write_bytes(b"keep")
    assert run([*argv, "--out", str(out), "--force"]) == 2
    assert capsys.readouterr().err.strip() == err
    assert out.read_bytes() == b"keep"
    out.unlink()
    assert not list(out.parent.glob(".*.part"))
    return err


def cut(src: Path, dst: Path, fraction: float) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[:int(len(data) * fraction)])
    return dst


def test_cut_tdms(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A TDMS file cut to half its size (npTDMS reads what it can and warns): an error naming
    the channel, the span it holds and the cut file; with --allow-partial an import whose gap is
    counted in the summary and in the metadata."""
    full = tdms(tmp_path / "full.tdms")
    m = str(write_map(tmp_path / "m.toml", TDMS_MAP))
    out = tmp_path / "o.mcap"
    half = cut(full, tmp_path / "half.tdms", 0.5)
    fails(capsys, [str(half), "--map", m], out,
          ["half.tdms: channel 'VIB_IP_1X' (for yB) holds no sample of the file's 0.0 s to",
           "the file ends early (npTDMS: Last segment of file has less data than expected)",
           "--allow-partial"])
    fails(capsys, [str(cut(full, tmp_path / "c95.tdms", 0.95)), "--map", m], out,
          ["c95.tdms: channel 'VIB_IP_1X' (for yB) holds 0.2 s to ", "of the file's 0.0 s to 60.0 s"])
    nb_only = str(write_map(tmp_path / "nb.toml", '[channels.nB]\nsource = "IP_SPEED"\n'))
    fails(capsys, [str(half), "--map", nb_only], out,
          ["half.tdms: the file ends early (npTDMS:", "it holds nB 0.0 s to"])
    assert run([str(half), "--map", m, "--out", str(out), "--allow-partial"]) == 0
    text = capsys.readouterr().out
    assert "PARTIAL (--allow-partial)" in text
    assert "partial: yB: holds no sample" in text and "partial: the file ends early" in text
    meta = metadata(out)
    assert meta["partial"] == "true" and meta["ends_early"].startswith("npTDMS: Last segment")
    nb, yb = orjson.loads(meta["channel.nB"]), orjson.loads(meta["channel.yB"])
    assert yb["samples"] == yb["written"] == 0
    assert yb["missing_s"] == pytest.approx(nb["last"] - nb["first"])  # all of what the file holds
    assert 0 < nb["samples"] < 6000 and nb["missing_s"] == 0.0
    assert set(read_back(out)) == {"nB"}


def test_cut_mdf4(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An MDF4 file cut short (in its metadata, or in its last data block with the metadata
    before it): one line saying so, naming the channels lost; --allow-partial cannot read it."""
    full = mdf4(tmp_path / "full.mf4")
    m = str(write_map(tmp_path / "m.toml", MF4_MAP))
    out = tmp_path / "o.mcap"
    fails(capsys, [str(cut(full, tmp_path / "half.mf4", 0.5)), "--map", m], out,
          ["half.mf4: not a readable MDF4 file: it ends early, at byte", "lies past it"])
    # a streaming writer's layout: the last group's data block at the end of the file, then cut
    data = bytearray(full.read_bytes())
    dgs = [i for i in range(0, len(data) - 4, 8) if data[i:i + 4] == b"##DG"]
    link = dgs[-1] + 24 + 2 * 8  # the last data group's data link
    (at,) = struct.unpack_from("<Q", data, link)
    (length,) = struct.unpack_from("<Q", data, at + 8)
    block = bytes(data[at:at + length])
    end = len(data) + (-len(data)) % 8
    data += b"\0" * (end - len(data)) + block
    struct.pack_into("<Q", data, link, end)
    (tmp_path / "moved.mf4").write_bytes(data)
    assert run([str(tmp_path / "moved.mf4"), "--map", m, "--out", str(out), "--quiet"]) == 0  # whole
    out.unlink()
    (tmp_path / "stream.mf4").write_bytes(data[:end + length // 2])
    for extra in ([], ["--allow-partial"]):
        fails(capsys, [str(tmp_path / "stream.mf4"), "--map", m, *extra], out,
              ["stream.mf4: not a readable MDF4 file: it ends early", "the data of channel group 2",
               "T_OIL", "no part of a cut MDF4 file can be read"])


def test_short_channel(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An MDF4 channel group ending 25 s before the others: an error naming the channel and its
    span; --allow-partial imports it, 25 s counted missing."""
    src = str(mdf4(tmp_path / "short.mf4", short_yb=25.0))
    m = str(write_map(tmp_path / "m.toml", MF4_MAP))
    out = tmp_path / "o.mcap"
    fails(capsys, [src, "--map", m], out,
          ["short.mf4: channel 'VIB_IP_1X' (for yB) holds 0.0 s to 35.0 s of the file's 0.0 s to 60.0 s"])
    assert run([src, "--map", m, "--out", str(out), "--allow-partial"]) == 0
    assert ("partial: yB: holds 0.0 s to 35.0 s of the file's 0.0 s to 60.0 s, 25.0 s (1000 samples "
            "at 40 Hz)") in capsys.readouterr().out
    yb = orjson.loads(metadata(out)["channel.yB"])
    assert yb["missing_s"] == pytest.approx(25.0) and yb["missing_samples"] == 1000
    check_values(read_back(out), {"yB": 0.1}, {"yB": (0.0, 35.0)})


def test_unit_conflict(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The map says rpm, the file rad/s: an error naming both, unless override = true (then the
    map's unit is taken); another name of the file's unit (1/min for rpm) is no conflict."""
    src = str(mdf4(tmp_path / "cell.mf4"))
    out = tmp_path / "o.mcap"
    m = write_map(tmp_path / "m.toml", MF4_MAP.replace('"IP_SPEED"\n', '"IP_SPEED"\nunit = "rpm"\n'))
    fails(capsys, [src, "--map", str(m)], out,
          ["cell.mf4: channel 'IP_SPEED' (for nB): the map says unit 'rpm', the file says 'rad/s'",
           "override = true"])
    m.write_text(m.read_text().replace('unit = "rpm"\n', 'unit = "rpm"\noverride = true\n'))
    assert run([src, "--map", str(m), "--out", str(out), "--quiet"]) == 0
    t, v = read_back(out)["nB"]
    assert np.allclose(v, n_b(t - START) / RPM_PER_RAD_S, atol=1e-3)  # taken as rpm, as told
    out.unlink()
    tdms_src = str(tdms(tmp_path / "cell.tdms"))
    m2 = write_map(tmp_path / "m2.toml", TDMS_MAP.replace('"IP_SPEED"\n', '"IP_SPEED"\nunit = "1/min"\n'))
    assert run([tdms_src, "--map", str(m2), "--out", str(out), "--quiet"]) == 0
    out.unlink()
    m3 = write_map(tmp_path / "m3.toml", TDMS_MAP.replace('"VIB_IP_1X"\n', '"VIB_IP_1X"\nunit = "in/s"\n'))
    fails(capsys, [tdms_src, "--map", str(m3)], out,
          ["channel 'VIB_IP_1X' (for yB): the map says unit 'in/s', the file says 'mm/s'"])
    m4 = write_map(tmp_path / "m4.toml", TDMS_MAP + "override = true\n")
    fails(capsys, [tdms_src, "--map", str(m4)], out, ["m4.toml: [channels.yB]: override", "needs unit"])


def test_other_bad_cases(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Blank cells set wrong, a folder as map or file, a missing channel, a wrong type: one line
    naming the path."""
    csv = str(mixed_csv(tmp_path / "cell.csv"))
    mf4 = str(mdf4(tmp_path / "cell.mf4"))
    out = tmp_path / "o.mcap"
    bad = write_map(tmp_path / "b.toml", CSV_MAP, CSV_TIME + '[csv]\nblank = "skip"\n')
    fails(capsys, [csv, "--map", str(bad)], out,
          ["b.toml: [csv]: blank must be one of auto, null, not-sampled"])
    write_map(bad, MF4_MAP + 'blank = "null"\n')
    fails(capsys, [mf4, "--map", str(bad)], out,
          ["b.toml: blank (what an empty cell means) is for CSV files only"])
    folder = tmp_path / "maps"
    folder.mkdir()
    fails(capsys, [csv, "--map", str(folder)], out, [f"map {folder}: is a folder, not a map file"])
    fails(capsys, [str(folder), "--map", str(bad)], out, [f"{folder}: is a folder, not a recording file"])
    write_map(bad, MF4_MAP.replace('"T_OIL"', '"T_FUEL"'))
    fails(capsys, [mf4, "--map", str(bad)], out, ["cell.mf4: no channel 'T_FUEL' (mapped to tA)"])
    with TdmsWriter(tmp_path / "text.tdms") as w:  # a channel of strings
        w.write_segment([RootObject({}), GroupObject("Engine", {}),
                         ChannelObject("Engine", "IP_SPEED", np.array(["fast", "slow"]),
                                       {"wf_start_time": np.datetime64(int(START), "s"),
                                        "wf_increment": 0.01})])
    write_map(bad, '[channels.nB]\nsource = "IP_SPEED"\n')
    fails(capsys, [str(tmp_path / "text.tdms"), "--map", str(bad)], out,
          ["text.tdms: channel 'IP_SPEED' (for nB): not a numeric channel"])
    write_map(bad, '[channels.nB]\nsource = "IP_SPEED"\nunit = "rpm"\noverride = "yes"\n')
    fails(capsys, [mf4, "--map", str(bad)], out, ["b.toml: [channels.nB]: override must be true or false"])
    fails(capsys, [mf4, "--map", str(write_map(bad, "[time]\nrate = 10.0\n" + MF4_MAP))], out,
          ["b.toml: an MDF4 file carries its own time"])
