"""A campaign: several pass-off runs of one engine with shutdown gaps, faults, noise.

Pure numerics: returns arrays and a ground-truth dictionary; writing files is
``simulator.export``'s job. Randomness: engine from child 0 of the seed, run r
from child r + 2 and faults from a separate child (1), so the first N runs of a
longer campaign equal an N-run campaign with the same seed, fault or not, and a
fault run equals the same run without the fault before the onset (its twin).
The schedule and the noise scale change what is drawn from those streams, never
which stream draws what: the same seed with the built-in schedule and noise
scale 1 gives the very same numbers as before either option existed.
The optional order phases (``PHASE_CHANNELS``) draw their noise and dropouts from a
further stream, child 0 of run r's, so every other channel is the same with or
without them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from node.contract import ORDER_CHANNELS, PHASE_CHANNELS, SENSOR_CHANNELS, engine_off, phase_channel
from node.contract.vector import wrap_degrees
from simulator import gaspath, rotor, thermal
from simulator.engine import Engine, build_engine, drawn_tracker
from simulator.schedule import (
    BUILT_IN_SCHEDULE,
    DEFAULT_OCS,
    DT,
    OC,
    Profile,
    SimSchedule,
    fault_candidates,
    make_profile,
)

# "imbalance-90": the imbalance fault with its phase chosen so that the added order vector is at
# right angles to the order's vector at the onset (the amplitude moves least for its size).
# "stiffness": yB's shaft loses stiffness (a crack or a loosened joint through the rotor, a softened
# bearing support), so every one of its modes softens and each critical falls by sqrt(factor);
# "stiffness-mode": the former fault, one mode alone (the 0.955 mode near the top speed).
FAULTS = ("imbalance", "imbalance-90", "stiffness", "stiffness-mode", "stuck-sensor", "drift")
STIFFNESS_FAULTS = ("stiffness", "stiffness-mode")
TRACKERS = ("fixed", "drawn")  # the order tracker's lag: rotor.TAU_TRACKER, or drawn per engine
CAMPAIGN_START = 1767600000.0  # 2026-01-05 08:00:00 UTC, epoch seconds
MAX_SPEEDS = {"nA": gaspath.NA_TOP, "nB": gaspath.NB_TOP, "nC": gaspath.NC_TOP}

# Sensor noise: sigma = (absolute + relative * |value|) x noise scale (default 1); then
# rounded to `decimals` (the rounding does not scale).
NOISE: dict[str, tuple[float, float, int]] = {
    #        absolute  relative  decimals
    "n": (1.0, 3e-4, 0),
    "y": (0.03, 0.02, 2),
    "t": (0.4, 0.0, 1),
    "p": (0.05, 5e-4, 1),
    "M1": (0.005, 0.0, 3),
    "M2": (0.05, 0.0, 1),
}
# Order phases (degrees): a vibration unit's phase comes from the same complex order as its
# amplitude, so its noise is the amplitude's noise over the amplitude, in radians:
# sigma = noise scale x (absolute + relative x A) / A for the "y" noise above, capped; below
# PHASE_MIN_AMPLITUDE (of the clean tracked amplitude) the unit gives no phase (null).
PHASE_MIN_AMPLITUDE = 0.1  # mm/s
PHASE_SIGMA_CAP = 45.0  # degrees
PHASE_DECIMALS = 1  # resolution 0.1 degree
DROPOUT_RATE = 2e-4  # isolated dropouts per sample and channel
BURSTS_PER_RUN = 0.5  # mean number of dropout bursts (5-60 samples) per channel and run
STIFFNESS_FAULT = 0.90  # stiffness factor of the softened modes after a stiffness fault
STIFFNESS_MODE = 2  # index of the one mode "stiffness-mode" softens among yB's (the 0.955 mode)
STIFFNESS_RAMP = 20.0  # s
DRIFT_RATE = 0.5 / 60.0  # yB drift, mm/s per second
IMBALANCE_FAULT = 0.9  # added imbalance, times the base imbalance of plane 1
# The three magnitudes above are a fault of size 1; ``fault_size`` scales the added imbalance,
# the stiffness loss (1 - STIFFNESS_FAULT) and the drift rate. A stuck sensor has no size.


@dataclass
class SimRun:
    """One simulated run: measured data on the 40 Hz grid and its ground truth."""

    t: np.ndarray  # (K,) epoch seconds, on the grid (no jitter)
    data: np.ndarray  # (K, len(SENSOR_CHANNELS)) measured values, NaN at dropouts
    truth: dict = field(default_factory=dict)
    # (K, len(PHASE_CHANNELS)) measured order phases, degrees in [-180, 180), NaN at dropouts
    # and below PHASE_MIN_AMPLITUDE; None when the campaign has no phases
    phase: np.ndarray | None = None


@dataclass
class Campaign:
    """All runs of one simulated engine, in time order."""

    runs: list[SimRun]
    channels: tuple[str, ...] = SENSOR_CHANNELS
    schedule: SimSchedule = BUILT_IN_SCHEDULE
    noise_scale: float = 1.0
    modes: dict[str, list[dict]] = field(default_factory=dict)  # the engine's (Engine.modes_truth)
    tracker_s: float = rotor.TAU_TRACKER  # the engine's order-tracker lag, s

    @property
    def ocs(self) -> tuple[OC, ...]:
        return self.schedule.ocs

    @property
    def published(self) -> tuple[str, ...]:
        """Every channel the campaign holds: ``channels`` then, if simulated, the phases."""
        return self.channels + (PHASE_CHANNELS if self.runs[0].phase is not None else ())


def _noise_spec(channel: str) -> tuple[float, float, int]:
    return NOISE.get(channel) or NOISE[channel[0]]


def _first_on(speeds: dict[str, np.ndarray]) -> tuple[int, int]:
    """Indices of the first and last sample where the engine is on (not ``engine_off``: some
    shaft speed is >= 5 % of its maximum)."""
    on = ~engine_off(np.column_stack([speeds[name] for name in MAX_SPEEDS]),
                     np.array(list(MAX_SPEEDS.values()), dtype=float))
    idx = np.flatnonzero(on)
    return int(idx[0]), int(idx[-1])


def _measure(
    rng: np.random.Generator,
    clean: dict[str, np.ndarray],
    channels: tuple[str, ...],
    noise_scale: float = 1.0,
) -> np.ndarray:
    """Add noise, quantise, clip amplitudes, insert dropouts: (K, C) float with NaN.

    noise_scale multiplies every sigma (absolute and relative part); the draws are the
    same for every scale (x 1.0 is exact: scale 1 gives the very same numbers).
    """
    k = len(clean["nB"])
    data = np.empty((k, len(channels)))
    for j, name in enumerate(channels):
        absolute, relative, decimals = _noise_spec(name)
        x = clean[name]
        noisy = x + rng.standard_normal(k) * (noise_scale * (absolute + relative * np.abs(x)))
        if name[0] in "ny":
            noisy = np.clip(noisy, 0.0, None)
        data[:, j] = np.round(noisy, decimals)
    _dropouts(rng, data)
    return data


def _dropouts(rng: np.random.Generator, data: np.ndarray) -> None:
    """Set isolated dropouts and dropout bursts to NaN in ``data`` (K, C), in place."""
    k = len(data)
    drop = rng.random(data.shape) < DROPOUT_RATE
    for j in range(data.shape[1]):
        for _ in range(rng.poisson(BURSTS_PER_RUN)):
            start = rng.integers(0, k)
            drop[start : start + rng.integers(5, 61), j] = True
    data[drop] = np.nan


def phase_sigma(amplitude: np.ndarray, noise_scale: float = 1.0) -> np.ndarray:
    """Phase noise sigma (degrees) at a clean tracked amplitude (mm/s), any shape.

    The amplitude's noise sigma over the amplitude (radians), times ``noise_scale``,
    capped at PHASE_SIGMA_CAP; amplitudes below PHASE_MIN_AMPLITUDE count as it.

    >>> phase_sigma(np.array([0.1, 1.0, 10.0])).round(2)
    array([18.33,  2.86,  1.32])
    """
    absolute, relative, _ = _noise_spec(ORDER_CHANNELS[0])
    a = np.maximum(amplitude, PHASE_MIN_AMPLITUDE)
    return np.minimum(noise_scale * np.degrees((absolute + relative * a) / a), PHASE_SIGMA_CAP)


def _measure_phase(
    rng: np.random.Generator, clean: dict[str, np.ndarray], noise_scale: float = 1.0
) -> np.ndarray:
    """Measured order phases (K, len(PHASE_CHANNELS)), degrees in [-180, 180), NaN for none.

    clean: the tracked amplitudes (mm/s) under ORDER_CHANNELS and their phases (degrees)
    under PHASE_CHANNELS. Noise ``phase_sigma``, rounded to PHASE_DECIMALS, null where
    the clean amplitude is below PHASE_MIN_AMPLITUDE, then dropouts as every channel's.
    """
    k = len(clean[ORDER_CHANNELS[0]])
    data = np.empty((k, len(PHASE_CHANNELS)))
    for j, name in enumerate(ORDER_CHANNELS):
        amp = clean[name]
        noisy = clean[phase_channel(name)] + rng.standard_normal(k) * phase_sigma(amp, noise_scale)
        col = np.round(wrap_degrees(noisy), PHASE_DECIMALS)
        col[col >= 180.0] = -180.0  # rounded up to the bound: the same angle
        col[amp < PHASE_MIN_AMPLITUDE] = np.nan
        data[:, j] = col
    _dropouts(rng, data)
    return data


def _fault_onset(rng: np.random.Generator, profile: Profile) -> tuple[float, str]:
    """Onset (s from run start) inside the plateau of one of the middle OCs, and that OC.

    The middle OCs: ``schedule.fault_candidates`` (OC6..OC10 of the built-in schedule).
    """
    candidates = fault_candidates(profile.segments)
    seg = candidates[rng.integers(len(candidates))]
    return seg.steady_start + rng.uniform(0.2, 0.6) * (seg.end - seg.steady_start), seg.name


def simulate_run(
    engine: Engine,
    rng: np.random.Generator,
    shutdown: float,
    history: dict,
    fault: str | None = None,
    fault_rng: np.random.Generator | None = None,
    plateau_scale: float = 1.0,
    fault_size: float = 1.0,
    ocs: tuple[OC, ...] = DEFAULT_OCS,
) -> tuple[dict[str, np.ndarray], Profile, dict, dict]:
    """Simulate one run's clean signals.

    shutdown: seconds since the previous run stopped (inf for a cold engine);
    history: the previous run's end state ({"metal", "slow", "ambient"}), or {}.
    fault_size: scales the fault's magnitude (see ``simulate_campaign``); ocs: the schedule.
    Returns (clean signals by channel, profile, run truth, end state).
    """
    profile = make_profile(rng, ocs, plateau_scale=plateau_scale)
    ambient = gaspath.Ambient(
        temperature=float(np.clip(rng.normal(12.0, 7.0), -15.0, 35.0)),
        pressure=float(rng.normal(101.3, 1.2)),
    )
    fuel_off_index = int(np.searchsorted(profile.t, profile.fuel_off))
    sig = gaspath.spools(profile.command, fuel_off_index)
    amb = ambient.temperature
    if history:
        metal0 = thermal.cooled(history["metal"], amb, shutdown, thermal.TAU_COOL_METAL)
        slow0 = {
            k: thermal.cooled(v, amb, shutdown, gaspath.TAU_COOL_GAS)
            for k, v in history["slow"].items()
        }
    else:
        metal0, slow0 = amb, {}
    sig.update(gaspath.gas_path(profile.command, sig["nB"], ambient, slow0))
    metal = thermal.metal_temperature(gaspath.metal_drive(sig), metal0)

    k = len(profile.t)
    heal = thermal.bow_decay(sig["nB"] / gaspath.NB_TOP)
    truth_run: dict = {
        "ambient_temperature_C": round(ambient.temperature, 3),
        "ambient_pressure_kPa": round(ambient.pressure, 3),
        "metal_temperature_start_C": round(metal0, 3),
        "metal_temperature_end_C": round(float(metal[-1]), 3),
        "imbalance": {},
        "bow_start_mm": {},
    }
    onset = None
    if fault is not None:
        assert fault_rng is not None
        onset, onset_oc = _fault_onset(fault_rng, profile)
        truth_run["fault"] = {
            "kind": fault, "onset_s": onset, "oc": onset_oc, "channel": "yB",
            "size": float(fault_size),
        }
    after = profile.t >= onset if onset is not None else np.zeros(k, dtype=bool)

    truth_run["criticals"] = {}
    for shaft in engine.shafts:
        base = engine.unbalance[shaft.out]
        # Run-to-run: components re-seat, the imbalance of each plane shifts by ~25 %.
        spread = 0.25 * np.abs(base) * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
        u_run = base + spread
        unbalance = np.full(k, u_run.sum(), dtype=complex)  # the planes' sum: every mode sees it
        b0 = thermal.bow_at_start(engine.bow_max[shaft.out], shutdown) * rng.uniform(0.7, 1.3)
        bow = b0 * np.exp(1j * rng.uniform(0, 2 * np.pi)) * heal
        stiffness = None
        if fault in ("imbalance", "imbalance-90") and shaft.out == "yB":
            assert fault_rng is not None
            extra = (IMBALANCE_FAULT * fault_size * abs(base[0])
                     * np.exp(1j * fault_rng.uniform(0, 2 * np.pi)))
            if fault == "imbalance-90":
                extra = _right_angle(shaft, sig[shaft.speed], metal, unbalance, bow, after, abs(extra))
                truth_run["fault"]["angle_deg"] = 90.0
            unbalance[after] += extra
        if fault in STIFFNESS_FAULTS and shaft.out == "yB":
            stiffness = stiffness_loss(fault, len(shaft.modes), profile.t - onset, fault_size)
        steady = rotor.order(shaft, sig[shaft.speed], metal, unbalance, bow, stiffness)
        vector = rotor.tracked(steady, engine.tracker_s)
        sig[shaft.out] = rotor.tracked_amplitude(vector)
        sig[phase_channel(shaft.out)] = rotor.tracked_phase(vector)
        truth_run["imbalance"][shaft.out] = [
            [round(abs(u), 7), round(float(np.degrees(np.angle(u))), 2)] for u in u_run
        ]
        truth_run["bow_start_mm"][shaft.out] = round(abs(b0), 7)
        truth_run["criticals"][shaft.out] = crossings(shaft, profile.t, sig[shaft.speed], metal, stiffness,
                                                      np.abs(steady))
    sig["metal"] = metal
    end_state = {
        "metal": float(metal[-1]),
        "slow": {name: float(sig[name][-1]) for name in gaspath.SLOW_TEMPS},
    }
    return sig, profile, truth_run, end_state


def stiffness_loss(fault: str, n_modes: int, since_onset: np.ndarray, size: float = 1.0
                   ) -> dict[int, np.ndarray]:
    """Per-mode stiffness factor (K,) of a stiffness fault, by mode index: 1 before the onset,
    then down to 1 - (1 - STIFFNESS_FAULT) x size over STIFFNESS_RAMP seconds; every mode of the
    shaft for "stiffness", mode STIFFNESS_MODE alone for "stiffness-mode".

    since_onset: (K,) s from the onset (negative before it).

    >>> k = stiffness_loss("stiffness", 3, np.array([-1.0, 10.0, 60.0]))
    >>> sorted(k), [round(float(v), 3) for v in k[0]]
    ([0, 1, 2], [1.0, 0.95, 0.9])
    >>> sorted(stiffness_loss("stiffness-mode", 3, np.array([60.0])))
    [2]
    """
    ramp = np.clip(since_onset / STIFFNESS_RAMP, 0.0, 1.0)
    factor = 1.0 - (1.0 - STIFFNESS_FAULT) * size * ramp
    modes = range(n_modes) if fault == "stiffness" else (STIFFNESS_MODE,)
    return {i: factor for i in modes}


def _right_angle(shaft: rotor.Shaft, speed: np.ndarray, metal: np.ndarray, unbalance: np.ndarray,
                 bow: np.ndarray, after: np.ndarray, size: float) -> complex:
    """The added imbalance (complex mm, modulus ``size``) whose steady order vector at the
    onset (first sample of ``after``) leads the order vector there by 90 degrees."""
    i = int(np.argmax(after))
    one = slice(i, i + 1)
    total = rotor.order(shaft, speed[one], metal[one], unbalance[one], bow[one])[0]
    gain = rotor.order(shaft, speed[one], metal[one], np.ones(1, dtype=complex),
                       np.zeros(1, dtype=complex))[0]
    return complex(size * np.exp(1j * (np.angle(total) - np.angle(gain) + np.pi / 2)))


def crossings(shaft: rotor.Shaft, t: np.ndarray, speed: np.ndarray, metal: np.ndarray,
              stiffness: dict[int, np.ndarray] | None = None,
              amplitude: np.ndarray | None = None) -> list[dict]:
    """Every crossing of a critical speed in a run (ground truth), in time order.

    t: (K,) s from the run's start; speed: (K,) shaft rpm (clean); metal: (K,) °C; stiffness:
    per-mode fault factor (K,); amplitude: (K,) the steady 1x amplitude (mm/s). One dict per
    crossing: ``mode`` (index), ``t_s`` (s from the run's start), ``speed`` (the critical
    speed then, rpm), ``rate_rpm_s`` (the shaft's speed rate then, + up, - down), ``zeta`` and
    ``af`` (1 / (2 zeta)) of the mode, ``amplitude`` (the steady 1x amplitude then, mm/s;
    with ``amplitude``).
    """
    out = []
    rate = np.gradient(speed, t)
    for i, mode in enumerate(shaft.modes):
        k = 1.0 if stiffness is None or i not in stiffness else stiffness[i]
        crit = np.broadcast_to(rotor.critical_rpm(mode, metal, k), speed.shape)
        d = speed - crit
        for j in np.flatnonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0):
            f = d[j] / (d[j] - d[j + 1])  # linear interpolation between samples j and j + 1
            c = {
                "mode": i,
                "t_s": round(float(t[j] + f * (t[j + 1] - t[j])), 4),
                "speed": round(float(crit[j] + f * (crit[j + 1] - crit[j])), 3),
                "rate_rpm_s": round(float(rate[j] + f * (rate[j + 1] - rate[j])), 3),
                "zeta": round(mode.zeta, 6),
                "af": round(1.0 / (2.0 * mode.zeta), 4),
            }
            if amplitude is not None:
                c["amplitude"] = round(float(amplitude[j] + f * (amplitude[j + 1] - amplitude[j])), 4)
            out.append(c)
    return sorted(out, key=lambda c: c["t_s"])


def _sensor_fault(
    data: np.ndarray, t: np.ndarray, kind: str | None, onset: float | None, size: float = 1.0
) -> None:
    """Apply a yB sensor fault in place (stuck value or drift) from ``onset`` (s from run start).

    size: scales the drift rate; a stuck sensor ignores it.
    """
    if kind not in ("stuck-sensor", "drift") or onset is None:
        return
    j = SENSOR_CHANNELS.index("yB")
    after = t >= onset
    col = data[:, j]
    if kind == "stuck-sensor":
        first = int(np.argmax(after))
        held = col[:first][~np.isnan(col[:first])]
        value = held[-1] if held.size else 0.0
        col[after] = value
    else:
        col[after] = np.round(col[after] + DRIFT_RATE * size * (t[after] - onset), 2)


def simulate_campaign(
    runs: int,
    seed: int,
    fault: str | None = None,
    plateau_scale: float = 1.0,
    fault_seed: int | None = None,
    fault_size: float = 1.0,
    schedule: SimSchedule | None = None,
    noise_scale: float = 1.0,
    phase: bool = True,
    tracker: str = "fixed",
) -> Campaign:
    """Simulate ``runs`` consecutive pass-off runs of one engine; the fault hits the last run.

    fault_seed: draws the fault's onset (OC, time) and phase from its own stream, so one
    engine and run can carry the fault at different places (default: from ``seed``).
    fault_size: scales the fault (1 = nominal): the added imbalance (IMBALANCE_FAULT x base
    imbalance of plane 1), the stiffness loss (factor 1 - (1 - STIFFNESS_FAULT) x size, which
    must stay > 0) and the drift rate (DRIFT_RATE); a stuck sensor ignores it. Same draws for
    every size, so sizes differ only in magnitude.
    schedule: the OCs each run goes through (default the built-in 12, ``BUILT_IN_SCHEDULE``;
    ``schedule.load_sim_schedule`` reads a file). noise_scale: multiplies every sensor noise
    sigma (> 0, default 1); same draws for every scale.
    phase: also measure the order phases (``SimRun.phase``, ``PHASE_CHANNELS``), from their
    own stream: every other number is the same with or without them.
    tracker: "fixed" (the order tracker lags ``rotor.TAU_TRACKER`` s on every engine) or "drawn"
    (each engine's lag drawn in ``rotor.TRACKER_RANGE`` from a stream of its own,
    ``engine.drawn_tracker``; every other draw the same).
    """
    schedule = BUILT_IN_SCHEDULE if schedule is None else schedule
    if not (np.isfinite(noise_scale) and noise_scale > 0):
        raise ValueError(f"noise_scale must be > 0 and finite, got {noise_scale!r}")
    if runs < 1:
        raise ValueError("runs must be >= 1")
    if tracker not in TRACKERS:
        raise ValueError(f"tracker must be one of {TRACKERS}, got {tracker!r}")
    if fault is not None and fault not in FAULTS:
        raise ValueError(f"unknown fault {fault!r}")
    if not (np.isfinite(fault_size) and fault_size > 0):
        raise ValueError(f"fault_size must be > 0 and finite, got {fault_size!r}")
    if fault in STIFFNESS_FAULTS and 1.0 - (1.0 - STIFFNESS_FAULT) * fault_size <= 1e-9:
        raise ValueError(
            f"fault_size {fault_size!r} leaves no stiffness (factor 1 - "
            f"{1.0 - STIFFNESS_FAULT:.2g} x size must be > 0)"
        )
    seq = np.random.SeedSequence(seed)
    engine_ss, fault_ss, *run_ss = seq.spawn(2 + runs)
    engine_rng = np.random.default_rng(engine_ss)
    engine = build_engine(engine_rng, np.random.default_rng(engine_ss.spawn(1)[0]))
    if tracker == "drawn":
        engine = dataclasses.replace(engine, tracker_s=drawn_tracker(seed))
    clock = CAMPAIGN_START + float(engine_rng.integers(0, 4 * 3600))
    history: dict = {}
    last_stop: float | None = None
    out: list[SimRun] = []
    for r in range(runs):
        rng = np.random.default_rng(run_ss[r])
        # Shutdown (cooling) time before this run: 10 min to 12 h, log-uniform.
        gap = float(np.exp(rng.uniform(np.log(600.0), np.log(12 * 3600.0))))
        shutdown = np.inf if r == 0 else gap
        is_faulty = fault is not None and r == runs - 1
        sig, profile, truth_run, history = simulate_run(
            engine,
            rng,
            shutdown,
            history,
            fault if is_faulty else None,
            np.random.default_rng(fault_ss if fault_seed is None
                                  else np.random.SeedSequence([seed, fault_seed, 0xFA17]))
            if is_faulty else None,
            plateau_scale,
            fault_size,
            schedule.ocs,
        )
        on_first, on_last = _first_on(sig)
        start = clock if last_stop is None else last_stop + gap - on_first * DT
        t = start + profile.t
        data = _measure(rng, sig, SENSOR_CHANNELS, noise_scale)
        phases = None
        if phase:
            phase_rng = np.random.default_rng(run_ss[r].spawn(1)[0])
            phases = _measure_phase(phase_rng, sig, noise_scale)
        onset = truth_run.get("fault", {}).get("onset_s")
        _sensor_fault(data, profile.t, fault if is_faulty else None, onset, fault_size)
        truth_run.update(
            {
                "index": r,
                "start": float(t[0]),
                "end": float(t[-1]),
                "engine_start": float(t[on_first]),
                "engine_stop": float(t[on_last] + DT),
                "shutdown_before_s": None if r == 0 else gap,
                "ocs": [
                    {
                        "name": s.name,
                        "speed": s.speed,
                        "transition_start": float(start + s.transition_start),
                        "steady_start": float(start + s.steady_start),
                        "end": float(start + s.end),
                    }
                    for s in profile.segments
                ],
            }
        )
        if "fault" in truth_run:
            truth_run["fault"]["onset"] = float(start + truth_run["fault"]["onset_s"])
        for crossed in truth_run["criticals"].values():
            for c in crossed:
                c["t"] = float(start + c["t_s"])
        out.append(SimRun(t=t, data=data, truth=truth_run, phase=phases))
        last_stop = float(t[on_last] + DT)
    return Campaign(runs=out, schedule=schedule, noise_scale=float(noise_scale),
                    modes=engine.modes_truth(), tracker_s=engine.tracker_s)
