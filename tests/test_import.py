"""``ordervib import``: a simulated recording written as ASAM MDF4 (asammdf), NI TDMS (npTDMS)
and CSV, in other names, units and sample rates, imported back and checked against the source
(the resampling, exactly) and against the original recording (the round trip); bad maps and
files end in one line, exit 2, no output.

The sources are the simulated campaign's samples (2 short runs, 24 channels) linearly
interpolated to the source's own times (phases along the shorter arc), so the imported
recording must hold, at each 40 Hz slot, the linear interpolation of the source there.
"""

from __future__ import annotations

import csv
import datetime as dt
import math
from itertools import islice
from pathlib import Path

import numpy as np
import orjson
import pytest
from asammdf import MDF, Signal
from mcap_spec import check_indexed
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from node.cli import main
from node.contract import FS, PHASE_CHANNELS, SENSOR_CHANNELS, decode_samples, parse_sensor_key
from node.contract.vector import wrap_degrees
from node.mcap import iter_messages, read_payloads
from node.training.runs import read_runs
from simulator.campaign import Campaign, simulate_campaign
from simulator.export import write_recording

CHANNELS = SENSOR_CHANNELS + PHASE_CHANNELS
BED = "cell7"
SEED = 3

# The source's unit per channel kind and the factor to the contract's unit (written here on
# their own, not taken from node.ingest.units): contract = source * a + b.
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
MM_PER_IN = 25.4
KPA_PER_PSI = 6.894757293168361


def _src_name(ch: str) -> str:
    return f"CELL.{ch.upper()}_RAW"


def _units(fmt: str) -> dict[str, tuple[str | None, float, float, dict]]:
    """Per contract channel: (unit written in the file or map, a, b, extra map keys)."""
    out: dict[str, tuple[str | None, float, float, dict]] = {}
    for ch in CHANNELS:
        if ch in PHASE_CHANNELS:
            if ch == "yB_ph":  # a lead in radians
                out[ch] = ("rad", -180.0 / math.pi, 0.0, {"convention": "lead"})
            else:
                out[ch] = ("rad", 180.0 / math.pi, 0.0, {})
        elif ch[0] == "n":
            out[ch] = ("rad/s", RPM_PER_RAD_S, 0.0, {}) if fmt != "csv" else ("Hz", 60.0, 0.0, {})
        elif ch[0] == "y":
            if ch == "yB":  # an rms amplitude
                out[ch] = ("in/s", MM_PER_IN * math.sqrt(2.0), 0.0, {"detection": "rms"})
            else:
                out[ch] = ("in/s", MM_PER_IN, 0.0, {})
        elif ch[0] == "t":
            out[ch] = ("degF", 5.0 / 9.0, -32.0 * 5.0 / 9.0, {}) if fmt != "csv" else ("K", 1.0, -273.15, {})
        elif ch[0] == "p":
            out[ch] = ("psi", KPA_PER_PSI, 0.0, {}) if fmt != "csv" else ("bar", 100.0, 0.0, {})
        else:  # M1, M2: given as scale and offset
            out[ch] = (None, 2.0, 1.0, {"scale": 2.0, "offset": 1.0})
    return out


def _interp(tq: np.ndarray, t: np.ndarray, v: np.ndarray, phase: bool = False) -> np.ndarray:
    """Linear interpolation of v (NaN: dropout) at tq; NaN where a neighbour is one; phases
    (degrees) unwrapped first and wrapped after (np.interp, np.unwrap: not the importer's code)."""
    nan = np.isnan(v)
    u = np.where(nan, 0.0, v)
    if phase and (~nan).any():
        u[~nan] = np.degrees(np.unwrap(np.radians(v[~nan])))
    x = np.interp(tq, t, u)
    x[np.interp(tq, t, nan.astype(float)) > 0] = np.nan
    return wrap_degrees(x) if phase else x


def _values(campaign: Campaign, r: int) -> np.ndarray:
    """Run r's simulated samples of every channel (K, 24), the contract's units."""
    run = campaign.runs[r]
    assert run.phase is not None
    return np.column_stack([run.data, run.phase])


def _source(campaign: Campaign, times: list[np.ndarray]) -> np.ndarray:
    """The contract-unit values of every channel at the source times (one array per run)."""
    cols = []
    for r, tq in enumerate(times):
        run, v = campaign.runs[r], _values(campaign, r)
        cols.append(np.column_stack([_interp(tq, run.t, v[:, j], CHANNELS[j] in PHASE_CHANNELS)
                                     for j in range(len(CHANNELS))]))
    return np.vstack(cols)


def _to_file_units(x: np.ndarray, fmt: str) -> np.ndarray:
    """Contract values (n, 24) in the file's units (the inverse of _units)."""
    u = _units(fmt)
    out = np.empty_like(x)
    for j, ch in enumerate(CHANNELS):
        _, a, b, _ = u[ch]
        out[:, j] = (x[:, j] - b) / a
    return out


def _map(path: Path, fmt: str, time: str, units_in_map: bool) -> Path:
    lines = [f'bed = "{BED}"', f'format = "{fmt}"', time, ""]
    for ch, (unit, _, _, extra) in _units(fmt).items():
        lines.append(f"[channels.{ch}]")
        lines.append(f'source = "{_src_name(ch) if fmt != "csv" else _csv_name(ch)}"')
        if unit is not None and units_in_map:
            lines.append(f'unit = "{unit}"')
        for k, v in extra.items():
            lines.append(f'{k} = {v!r}'.replace("'", '"'))
        lines.append("")
    path.write_text("\n".join(lines))
    return path


def _csv_name(ch: str) -> str:
    unit = _units("csv")[ch][0] or "-"
    return f"{ch.lower()} sensor [{unit}]"


RUN_S = 90.0  # s of each simulated run kept: the start-up and the first transitions


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Campaign]:
    """The simulated campaign (2 runs cut to their first 90 s, every channel with phases, the
    shutdown between them) and its recording (with the simulator's acquisition jitter)."""
    d = tmp_path_factory.mktemp("import")
    campaign = simulate_campaign(2, SEED, plateau_scale=0.05)
    n = int(RUN_S * FS)
    for run in campaign.runs:
        assert run.phase is not None
        run.t, run.data, run.phase = run.t[:n], run.data[:n], run.phase[:n]
    write_recording(campaign, d / "original.mcap", BED, SEED)
    return d, campaign


def _read_back(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per channel: (t, v) of the imported recording's messages, NaN for null."""
    for m in islice(iter_messages(path), 5000):  # log_time is t, publish_time the same
        t = orjson.loads(m.payload)["t"]
        assert m.log_time == m.publish_time == round(t * 1e9)
    got = {}
    for topic, payloads in read_payloads(path).items():
        parsed = parse_sensor_key(topic)
        assert parsed is not None and parsed[0] == BED
        t, v, ok = decode_samples(payloads)
        assert ok.all()
        got[parsed[1]] = (t, v)
    return got


def _check_round_trip(original: Path, out: Path) -> None:
    """The imported recording read as training reads it: the original's runs (count, start,
    length, shutdown before), channels, and values within what interpolation between
    neighbouring slots can move them."""
    before, after = read_runs(original), read_runs(out)
    assert len(after) == len(before) == 2
    for a, b in zip(after, before, strict=True):
        assert set(a.channels) == set(b.channels) == set(CHANNELS)
        assert abs(a.t[0] - b.t[0]) <= 1.01 / FS and abs(len(a.t) - len(b.t)) <= 2
        if b.shutdown_before is None:
            assert a.shutdown_before is None
        else:
            assert a.shutdown_before is not None and abs(a.shutdown_before - b.shutdown_before) <= 2.01 / FS
        _, ia, ib = np.intersect1d(np.round(a.t * FS), np.round(b.t * FS), return_indices=True)
        for ch in CHANNELS:
            x, y = a.column(ch)[ia], b.column(ch)[ib]
            phase = ch in PHASE_CHANNELS
            # a source sample lies within 25 ms of the slot, so between the simulated samples of
            # the slots k - 2 ... k + 2 (the original's clock phase is not the grid's)
            pad = np.concatenate([[np.nan] * 2, y, [np.nan] * 2])
            moves = [pad[2 + s:len(pad) - 2 + s] - y for s in (-2, -1, 1, 2)]
            bound = np.max([np.abs(wrap_degrees(m) if phase else m) for m in moves], axis=0)
            ok = np.isfinite(y) & np.isfinite(bound)  # the original and its neighbours measured
            # enough compared: a phase only where its order is above the unit's threshold (the LP
            # and HP shafts idle below their first critical: yA_ph 21 %, yC_ph 3.5 % of these slots)
            assert ok.sum() >= 100 and (phase or ok.mean() > 0.25), (ch, ok.sum())
            assert np.isfinite(x[ok]).all(), ch  # so the source was, around the slot: a value
            err = np.abs(wrap_degrees(x - y) if phase else x - y)[ok]
            assert np.all(err <= bound[ok] + 1e-6 * np.max(np.abs(y[ok]), initial=1.0)), ch


def _run_times(campaign: Campaign, step: float, rng: np.random.Generator | None = None) -> list[np.ndarray]:
    """Source times of each run: every ``step`` s over the run's span (jittered by up to 40 %)."""
    out = []
    for run in campaign.runs:
        t = np.arange(run.t[0], run.t[-1], step)
        if rng is not None:
            t[1:-1] += rng.uniform(-0.4, 0.4, len(t) - 2) * step
        out.append(t)
    return out


def test_mdf4_round_trip(sim: tuple[Path, Campaign]) -> None:
    """MDF4: 100 Hz (the phases 50 Hz, a group of their own), units in the file (rad/s, in/s rms,
    degF, psi, rad with one lead), times relative to the header's start time."""
    d, campaign = sim
    start = math.floor(campaign.runs[0].t[0]) - 7.0
    groups = {"fast": (0.01, [c for c in CHANNELS if c not in PHASE_CHANNELS]),
              "phase": (0.02, PHASE_CHANNELS)}
    mdf = MDF(version="4.10")
    mdf.header.start_time = dt.datetime.fromtimestamp(start, tz=dt.UTC)
    expected: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    units = _units("mf4")
    for step, names in groups.values():
        rel = np.concatenate(_run_times(campaign, step)) - start
        times = start + rel  # the very floats the importer computes
        x = _source(campaign, [t for t in np.split(times, np.flatnonzero(np.diff(times) > 1) + 1)])
        raw = _to_file_units(x, "mf4")
        sigs = []
        for ch in names:
            j = CHANNELS.index(ch)
            sigs.append(Signal(raw[:, j], rel, name=_src_name(ch), unit=units[ch][0] or ""))
            expected[ch] = (times, x[:, j])
        mdf.append(sigs)
    mdf.save(d / "cell.mf4", overwrite=True)
    mdf.close()
    m = _map(d / "mf4.toml", "mf4", "", units_in_map=False)  # the units come from the file
    out = d / "mf4.mcap"
    assert main(["import", str(d / "cell.mf4"), "--map", str(m), "--out", str(out), "--quiet"]) == 0
    check_indexed(out)
    got = _read_back(out)
    assert set(got) == set(CHANNELS)
    for ch, (times, x) in expected.items():  # the exact check, on each group's clock
        _check_exact_one(got[ch], times, x, ch)
    _check_round_trip(d / "original.mcap", out)


def _check_exact_one(got: tuple[np.ndarray, np.ndarray], times: np.ndarray, x: np.ndarray, ch: str) -> None:
    t, v = got
    spans = np.split(times, np.flatnonzero(np.diff(times) > 1.0) + 1)
    slots = np.concatenate([np.arange(math.ceil(s[0] * FS), math.floor(s[-1] * FS) + 1) for s in spans])
    assert np.array_equal(t, slots / FS), ch  # every 40 Hz slot of each run's span, and only those
    want = _interp(slots / FS, times, x, ch in PHASE_CHANNELS)
    assert np.array_equal(np.isnan(v), np.isnan(want)), ch
    ok = ~np.isnan(v)
    diff = wrap_degrees(v[ok] - want[ok]) if ch in PHASE_CHANNELS else v[ok] - want[ok]
    assert np.abs(diff).max(initial=0.0) <= 1e-9 * np.max(np.abs(want[ok]), initial=1.0), ch


def test_tdms_round_trip(sim: tuple[Path, Campaign]) -> None:
    """TDMS: one group, a relative time channel (s) at 100 Hz, the start in the map as an ISO
    date-time, units in the map."""
    d, campaign = sim
    start = math.floor(campaign.runs[0].t[0]) - 3.0
    rel = np.concatenate(_run_times(campaign, 0.01)) - start
    times = start + rel
    x = _source(campaign, np.split(times, np.flatnonzero(np.diff(times) > 1) + 1))
    raw = _to_file_units(x, "tdms")
    chans = [ChannelObject("Engine", "Time", rel)]
    chans += [ChannelObject("Engine", _src_name(ch), raw[:, j]) for j, ch in enumerate(CHANNELS)]
    with TdmsWriter(d / "cell.tdms") as w:
        w.write_segment([RootObject({}), GroupObject("Engine", {}), *chans])
    iso = dt.datetime.fromtimestamp(start, tz=dt.UTC).isoformat()
    m = _map(d / "tdms.toml", "tdms", f'[time]\ncolumn = "Engine/Time"\nstart = "{iso}"', units_in_map=True)
    out = d / "tdms.mcap"
    assert main(["import", str(d / "cell.tdms"), "--map", str(m), "--out", str(out), "--quiet"]) == 0
    check_indexed(out)
    got = _read_back(out)
    for j, ch in enumerate(CHANNELS):
        _check_exact_one(got[ch], times, x[:, j], ch)
    _check_round_trip(d / "original.mcap", out)


def test_csv_round_trip(sim: tuple[Path, Campaign]) -> None:
    """CSV: irregular times (80 Hz +- 40 %) in ms since a start given in the map, ';' between
    fields and a decimal comma, empty cells for dropouts, other units (Hz, K, bar)."""
    d, campaign = sim
    start = math.floor(campaign.runs[0].t[0])
    ms = np.round((np.concatenate(_run_times(campaign, 0.0125, np.random.default_rng(1))) - start) * 1e3, 3)
    times = ms * 1e-3 + start  # the arithmetic the importer does
    x = _source(campaign, np.split(times, np.flatnonzero(np.diff(times) > 1) + 1))
    raw = _to_file_units(x, "csv")
    with open(d / "cell.csv", "w", newline="") as f:
        f.write("exported by a test cell\n")
        w = csv.writer(f, delimiter=";")
        w.writerow(["time_ms", *(_csv_name(ch) for ch in CHANNELS)])
        for i in range(len(ms)):
            w.writerow([repr(float(ms[i])).replace(".", ","),
                        *("" if v != v else repr(float(v)).replace(".", ",") for v in raw[i])])
    m = _map(d / "csv.toml", "csv", f'[time]\ncolumn = "time_ms"\nunit = "ms"\nstart = {start}\n\n'
             '[csv]\ndelimiter = ";"\ndecimal = ","\nskip_rows = 1', units_in_map=True)
    out = d / "csv.mcap"
    assert main(["import", str(d / "cell.csv"), "--map", str(m), "--out", str(out), "--quiet"]) == 0
    check_indexed(out)
    got = _read_back(out)
    for j, ch in enumerate(CHANNELS):
        _check_exact_one(got[ch], times, x[:, j], ch)
    _check_round_trip(d / "original.mcap", out)


# -- the resampling rule on its own


def test_to_grid_gaps_dropouts_and_phase() -> None:
    """Slots between samples further apart than max_gap get nothing, slots next to a dropout a
    null, a slot on a sample that sample; a phase goes the shorter way round."""
    from node.ingest.resample import to_grid

    t = 1_767_600_000.0 + np.array([0.0, 0.05, 0.1, 2.1, 2.15, 2.2])
    v = np.array([0.0, 2.0, np.nan, 10.0, 12.0, 14.0])
    k, x = to_grid(t, v, max_gap=1.0)
    assert (k / FS - t[0]).round(6).tolist() == [0.0, 0.025, 0.05, 0.075, 0.1, 2.1, 2.125, 2.15, 2.175, 2.2]
    assert np.allclose(x, [0.0, 1.0, 2.0, np.nan, np.nan, 10.0, 11.0, 12.0, 13.0, 14.0], equal_nan=True)
    assert len(to_grid(t, v, max_gap=3.0)[0]) == 89  # bridged when allowed: 2.2 s at 40 Hz + 1
    _, ph = to_grid(t[3:], np.array([175.0, -175.0, -165.0]), max_gap=1.0, phase=True)
    assert np.allclose(ph, [175.0, 180.0 - 360.0, -175.0, -170.0, -165.0])


# -- small files for the other paths and the errors


def _small(d: Path) -> dict[str, Path]:
    """A 2 s CSV, MDF4 and TDMS (waveform timing) file of nB and yB at 100 Hz (nB a ramp), and a
    good map for each."""
    start = 1_767_600_000.0
    rel = np.arange(200) / 100.0
    nb, yb = 3000.0 + 500.0 * rel, 1.0 + 0.1 * rel
    with open(d / "s.csv", "w") as f:
        f.write("time,speed,amp\n")
        for a, b, c in zip(rel.tolist(), nb.tolist(), yb.tolist(), strict=True):
            f.write(f"{start + a!r},{b!r},{c!r}\n")
    mdf = MDF(version="4.10")
    mdf.header.start_time = dt.datetime.fromtimestamp(start, tz=dt.UTC)
    mdf.append([Signal(nb / 60.0, rel, name="speed", unit="Hz"), Signal(yb, rel, name="amp", unit="mm/s")])
    mdf.save(d / "s.mf4", overwrite=True)
    mdf.close()
    wf = {"wf_start_time": np.datetime64(int(start * 1e6), "us"), "wf_increment": 0.01}
    with TdmsWriter(d / "s.tdms") as w:
        w.write_segment([RootObject({}), GroupObject("g", {}),
                         ChannelObject("g", "speed", nb, {**wf, "unit_string": "rpm"}),
                         ChannelObject("g", "amp", yb, wf)])
    maps = {}
    for fmt, time in (("csv", '[time]\ncolumn = "time"\n'), ("mf4", ""), ("tdms", "")):
        maps[fmt] = d / f"{fmt}.toml"
        maps[fmt].write_text(f'bed = "b1"\n{time}\n[channels.nB]\nsource = "speed"\n'
                             '[channels.yB]\nsource = "amp"\n')
    files = {"csv": d / "s.csv", "mf4": d / "s.mf4", "tdms": d / "s.tdms"}
    return {**files, **{f"{k}_map": v for k, v in maps.items()}}


@pytest.mark.parametrize("fmt", ["csv", "mf4", "tdms"])
def test_small_files_exact(tmp_path: Path, fmt: str) -> None:
    """Each format's own clock (a time column, MDF4's header start, TDMS waveform timing) and
    unit (none: the contract's; Hz; the file's rpm): the ramp lands on the grid exactly."""
    f = _small(tmp_path)
    out = tmp_path / "o.mcap"
    assert main(["import", str(f[fmt]), "--map", str(f[f"{fmt}_map"]), "--out", str(out), "--quiet"]) == 0
    got = _read_back_bed(out, "b1")
    t, v = got["nB"]
    assert len(t) == 80 and t[0] == 1_767_600_000.0 and np.allclose(np.diff(t), 1 / FS)
    # epoch seconds as float64 resolve 0.24 us: 500 rpm/s x 0.24 us = 1.2e-4 rpm
    assert np.allclose(v, 3000.0 + 500.0 * (t - t[0]), rtol=0, atol=2e-4)
    assert np.allclose(got["yB"][1], 1.0 + 0.1 * (t - t[0]), rtol=0, atol=1e-7)
    check_indexed(out)


def _read_back_bed(path: Path, bed: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for topic, payloads in read_payloads(path).items():
        parsed = parse_sensor_key(topic)
        assert parsed is not None and parsed[0] == bed
        t, v, _ = decode_samples(payloads)
        out[parsed[1]] = (t, v)
    return out


def _fails(capsys: pytest.CaptureFixture[str], argv: list[str], out: Path, words: str) -> None:
    """The command ends with exit 2 and one line holding ``words``; ``out`` was not created."""
    code = main(["import", *argv, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("ordervib import: "), err
    assert words in err, err
    assert not out.exists()
    assert not list(out.parent.glob(".*.part"))


def test_bad_files_and_maps_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _small(tmp_path)
    out = tmp_path / "o.mcap"
    csv_map = str(f["csv_map"])
    _fails(capsys, [str(tmp_path / "none.csv"), "--map", csv_map], out, "file not found")
    (tmp_path / "text.mf4").write_text(f["csv"].read_text())
    _fails(capsys, [str(tmp_path / "text.mf4"), "--map", str(f["mf4_map"])], out, "not an MDF4 file")
    (tmp_path / "text.tdms").write_text(f["csv"].read_text())
    _fails(capsys, [str(tmp_path / "text.tdms"), "--map", str(f["tdms_map"])], out, "not a TDMS file")
    (tmp_path / "cut.mf4").write_bytes(f["mf4"].read_bytes()[:200])
    _fails(capsys, [str(tmp_path / "cut.mf4"), "--map", str(f["mf4_map"])], out, "not a readable MDF4 file")
    (tmp_path / "cut.tdms").write_bytes(f["tdms"].read_bytes()[:150])
    _fails(capsys, [str(tmp_path / "cut.tdms"), "--map", str(f["tdms_map"])], out, "cut.tdms: ")
    _fails(capsys, [str(f["mf4"]), "--map", csv_map], out, "an MDF4 file carries its own time")
    local = MDF(version="4.10")  # a start time kept as local time of no zone
    local.header.start_time = dt.datetime(2026, 1, 5, 8, 0, 0)
    local.append([Signal(np.arange(3.0), np.arange(3.0) / 100, name="speed", unit="rpm"),
                  Signal(np.arange(3.0), np.arange(3.0) / 100, name="amp", unit="mm/s")])
    local.save(tmp_path / "local.mf4", overwrite=True)
    local.close()
    _fails(capsys, [str(tmp_path / "local.mf4"), "--map", str(f["mf4_map"])], out,
           "start time 2026-01-05 08:00:00 is a local time without zone: give [time] start")
    _fails(capsys, [str(tmp_path / "s.xyz"), "--map", str(tmp_path / "none.toml")], out, "map file not found")

    def bad_map(text: str, src: Path = f["csv"], words: str = "") -> None:
        m = tmp_path / "bad.toml"
        m.write_text(text)
        _fails(capsys, [str(src), "--map", str(m)], out, words)

    good = '[time]\ncolumn = "time"\n[channels.nB]\nsource = "speed"\n'
    bad_map('bed = "b1"\n' + good.replace('"speed"', '"nope"'), words="no column 'nope' (mapped to nB)")
    bad_map('bed = "b1"\n[channels.nB]\nsource = "nope"\n', f["mf4"], "no channel 'nope' (mapped to nB)")
    bad_map('bed = "b1"\n[channels.nB]\nsource = "nope"\n', f["tdms"], "no channel 'nope'")
    bad_map('bed = "b1"\n' + good + 'unit = "furlong"\n', words="unit 'furlong' of nB")
    bad_map('bed = "b1"\n[channels.yB]\nsource = "amp"\nunit = "rpm"\n', f["mf4"], "unit 'rpm' of yB")
    bad_map('bed = "b1"\n' + good + '[channels.nX]\nsource = "amp"\n',
            words="[channels.nX]: not a contract channel")
    bad_map('bed = "b1"\n' + good + 'colour = "red"\n', words="unknown key 'colour'")
    bad_map('bed = "a/b"\n' + good, words="bed must be")
    bad_map('bed = "b1"\n[time]\ncolumn = "time"\n[channels]\n', words="[channels] must hold")
    bad_map('bed = "b1\n', words="not valid TOML")
    bad_map('bed = "b1"\n' + good.replace('[time]\n', '[time]\nstart = 2026-01-05T08:00:00\n'),
            words="start needs its zone")
    bad_map('bed = "b1"\n' + good.replace('[time]\n', '[time]\nmax_gap = 60\n'), words="max_gap must be")
    # the CSV's times read as relative ones (no start) are no epoch times
    (tmp_path / "rel.csv").write_text("time,speed\n0.0,1\n0.01,2\n")
    bad_map('bed = "b1"\n' + good, tmp_path / "rel.csv", "relative times need [time] start")
    (tmp_path / "back.csv").write_text("time,speed\n1767600000.0,1\n1767600000.02,2\n1767600000.01,3\n")
    bad_map('bed = "b1"\n' + good, tmp_path / "back.csv", "times not increasing at sample 2")
    (tmp_path / "word.csv").write_text("time,speed\n1767600000.0,1\n1767600000.01,fast\n")
    bad_map('bed = "b1"\n' + good, tmp_path / "word.csv", "column 'speed', data row 2: 'fast' is no number")
    (tmp_path / "big.toml").write_text("#" * 70_000)
    _fails(capsys, [str(f["csv"]), "--map", str(tmp_path / "big.toml")], out,
           "more than the 65536 such a file may hold")


def test_existing_out_is_never_overwritten(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An existing --out is refused (exit 2, one line, the file as it was); --force replaces it
    with a complete recording."""
    f = _small(tmp_path)
    out = tmp_path / "o.mcap"
    out.write_bytes(b"keep")
    argv = ["import", str(f["csv"]), "--map", str(f["csv_map"]), "--out", str(out), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "exists" in err
    assert out.read_bytes() == b"keep"
    assert main([*argv, "--force"]) == 0
    assert check_indexed(out) == 160


def test_format_by_option_and_slots_bound(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A file of any name is read as --format says; a source whose 40 Hz grid would pass the
    bound per channel is refused before the grid is built."""
    f = _small(tmp_path)
    dat = tmp_path / "s.dat"
    dat.write_bytes(f["csv"].read_bytes())
    out = tmp_path / "o.mcap"
    _fails(capsys, [str(dat), "--map", str(f["csv_map"])], out, "which format?")
    assert main(["import", str(dat), "--map", str(f["csv_map"]), "--format", "csv", "--out", str(out),
                 "--quiet"]) == 0
    assert check_indexed(out) == 160
    (tmp_path / "long.csv").write_text("time,speed,amp\n" + "".join(
        f"{1_767_600_000.0 + 0.9 * i!r},1,1\n" for i in range(600_000)))  # 6.25 days at 40 Hz
    _fails(capsys, [str(tmp_path / "long.csv"), "--map", str(f["csv_map"])], tmp_path / "o2.mcap",
           "more than 20000000 per channel")


def test_the_command_line_imports_neither_library() -> None:
    """asammdf and npTDMS are imported only when a file of theirs is read: the node and every
    other command run without them."""
    import subprocess
    import sys

    code = ("import sys; from node.cli import build_parser; import node.ingest; build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('asammdf', 'nptdms')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


def test_mdf4_name_in_two_groups_needs_group(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A name found in two MDF4 channel groups is refused in one line unless the map names the
    group; then that group's channel is read (here at 50 Hz, its own clock)."""
    start = 1_767_600_000.0
    mdf = MDF(version="4.10")
    mdf.header.start_time = dt.datetime.fromtimestamp(start, tz=dt.UTC)
    fast, slow = np.arange(100) / 100.0, np.arange(50) / 50.0
    mdf.append([Signal(1000.0 + 0 * fast, fast, name="speed", unit="rpm")])
    mdf.append([Signal(2000.0 + 100.0 * slow, slow, name="speed", unit="rpm")])
    mdf.save(tmp_path / "two.mf4", overwrite=True)
    mdf.close()
    m = tmp_path / "m.toml"
    m.write_text('bed = "b1"\n[channels.nB]\nsource = "speed"\n')
    out = tmp_path / "o.mcap"
    _fails(capsys, [str(tmp_path / "two.mf4"), "--map", str(m)], out, "in channel groups 0, 1: give group")
    m.write_text('bed = "b1"\n[channels.nB]\nsource = "speed"\ngroup = 1\n')
    assert main(["import", str(tmp_path / "two.mf4"), "--map", str(m), "--out", str(out), "--quiet"]) == 0
    t, v = _read_back_bed(out, "b1")["nB"]
    assert len(t) == 40 and np.allclose(v, 2000.0 + 100.0 * (t - start), rtol=0, atol=1e-4)  # 0.24 us
