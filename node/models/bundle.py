"""Model bundles: a directory with ``manifest.json`` and ``arrays.npz``.

Nothing in a bundle executes code on load: metadata is JSON, arrays are read
as float64 only, never pickles. A bundle is untrusted input: the manifest is read
bounded (size, nesting depth, integer digits: ``node.contract.documents``), every
array member must be one the manifest expects and is checked (dtype, element count,
declared size) before it is decompressed, and every run-time setting has a range
(``node.models.config``). A bundle whose format, version, array hash, arrays or
settings do not pass is refused with a one-line OrdervibError naming the bundle and
what is wrong.

A model folder holds one target or several (``Model``). One target is a bundle of
format 2 (as before, readable by older versions); several are format 3: a
``manifest.json`` naming the targets, and per target a sub-folder of that name holding
its format-2 bundle. The targets share the schedule and the run-time settings.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from node import __version__
from node.contract import FS, RESERVED_NAMES
from node.contract.documents import NPZ_OVERHEAD, parse_json, read_bounded, read_document, read_npz
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.models.config import BEFORE_GUARD, V1_SETTINGS, RuntimeConfig, SettingError
from node.models.envelope import Envelope
from node.models.forecast import PeakTable
from node.models.kinds import model_from_arrays
from node.models.ocmodel import RUN_CURVE
from node.models.plateau import PlateauShift
from node.models.result import Calibration, OCResult
from node.models.settle import SettleAnchor
from node.models.transients import FleetTransients

FORMAT = "ordervib-model"
FORMAT_VERSION = 2  # 2: the run-time settings are stored ("runtime"); 1 is read with the defaults
READABLE_VERSIONS = (1, 2)
MULTI_VERSION = 3  # several targets: one format-2 bundle per target, in a sub-folder named by it
_TARGET_NAME = re.compile(r"^[A-Za-z0-9_]+$")  # a target's sub-folder name: no path of its own
MANIFEST = "manifest.json"
ARRAYS = "arrays.npz"
ENVELOPE_PREFIX = "envelope:"  # an OC's envelope arrays: "envelope:<OC>/<name>"
ENVELOPE_ARRAYS = ("low", "high", "mean", "whiten")
CURVE_ARRAYS = ("curve/speed", "curve/mean")
# Bounds of the arrays file. The demo's largest bundle holds 189 arrays, 235 kB in all, the
# largest 583 values: a thousand times more is still a bundle, beyond it is not one.
MAX_ARRAY_ELEMENTS = 1 << 22  # values in one array (32 MiB of float64)
MAX_ARRAYS_BYTES = 256 << 20  # the arrays' bytes, all members together (uncompressed)


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class Bundle:
    """A trained switching model: per-OC results, schedule, target, provenance."""

    method: str
    target: str
    schedule: Schedule
    ocs: list[OCResult]
    config: RuntimeConfig = field(default_factory=RuntimeConfig)
    training: dict = field(default_factory=dict)
    curve: tuple[np.ndarray, np.ndarray] | None = None  # characteristic curve (speeds, means)
    checks: dict = field(default_factory=dict)  # model-free checks, e.g. {"flatline_samples": 80}
    transients: FleetTransients | None = None  # the fleet's criticals per transition (None: not kept)
    forecast: PeakTable | None = None  # the training runs' peaks per segment (None: not kept, no forecast)

    @property
    def history_s(self) -> float:
        """Seconds of measured past kept to seed an OC's model (``config.history_s``)."""
        return self.config.history_s

    def oc(self, name: str) -> OCResult | None:
        for r in self.ocs:
            if r.name == name:
                return r
        return None

    @property
    def inputs(self) -> list[str]:
        """Every channel some OC model reads, sorted."""
        return sorted({c for r in self.ocs if r.model for c in r.inputs})


def _manifest_oc(r: OCResult) -> dict:
    d = {"name": r.name, "inputs": r.inputs, "params": r.params, "n_runs": r.n_runs,
         "train_eps": _num(r.train_eps), "cv_eps": _num(r.cv_eps), "note": r.note,
         "ranking": [[c, _num(s)] for c, s in r.ranking],
         "model": None, "residual": None}
    if r.model is not None:
        d["model"] = {"method": r.model.method.value, "repaired": r.model.repaired,
                      "n_states": r.model.n_states}
    if r.calibration is not None:
        c = r.calibration
        d["residual"] = {"sigma": c.sigma, "threshold": c.threshold,
                         "ewma_alpha": c.ewma_alpha, "persist": c.persist,
                         "cv_peaks": c.peaks}
    if r.envelope is not None:
        env = r.envelope.manifest()
        if r.outside_cv is not None:
            env["cv_outside"] = {"sum_z2": r.outside_cv[0], "samples": r.outside_cv[1]}
        d["envelope"] = env
    if r.plateau is not None:
        d["plateau"] = r.plateau.to_dict()
    if r.settle is not None:
        d["settle"] = r.settle.to_dict()
    return d


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def save_bundle(bundle: Bundle, path: str | os.PathLike) -> Path:
    """Write the bundle directory (created if needed); returns its path."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    for r in bundle.ocs:
        if r.model is not None:
            for k, v in r.model.arrays().items():
                arrays[f"{r.name}/{k}"] = np.asarray(v, dtype=float)
        if r.envelope is not None:
            for k, v in r.envelope.arrays().items():
                arrays[f"{ENVELOPE_PREFIX}{r.name}/{k}"] = v
    if bundle.curve is not None:
        arrays["curve/speed"], arrays["curve/mean"] = bundle.curve
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy's stub mistakes ** for allow_pickle
    data = buf.getvalue()
    (out / ARRAYS).write_bytes(data)
    manifest = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "created_by": f"ordervib {__version__}",
        "method": bundle.method, "target": bundle.target, "sample_rate_hz": FS,
        "runtime": bundle.config.to_dict(), "schedule": bundle.schedule.to_dict(),
        "training": bundle.training, "checks": bundle.checks, "ocs": [_manifest_oc(r) for r in bundle.ocs],
        "arrays_sha256": hashlib.sha256(data).hexdigest(),
    }
    if bundle.transients is not None:  # (older versions ignore it: their node has no transient topic)
        manifest["transients"] = bundle.transients.manifest()
    if bundle.forecast is not None:  # (older versions ignore it: their node has no verdict)
        manifest["forecast"] = bundle.forecast.manifest()
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return out


@dataclass(frozen=True, eq=False)
class Model:
    """A model folder's targets: one ``Bundle`` per target, sharing schedule and run-time settings.

    >>> from node.contract.schedule import OperatingCondition, Schedule
    >>> s = Schedule((OperatingCondition("A", 4000.0),))
    >>> m = Model((Bundle("lasso", "yA", s, []), Bundle("lasso", "yB", s, [])))
    >>> m.targets, m["yB"].target, m.schedule == s
    (['yA', 'yB'], 'yB', True)
    >>> Model((Bundle("lasso", "yA", s, []), Bundle("lasso", "yA", s, [])))
    Traceback (most recent call last):
    ...
    ValueError: target(s) repeated: yA
    """

    bundles: tuple[Bundle, ...]

    def __post_init__(self) -> None:
        if not self.bundles:
            raise ValueError("a model holds at least one target")
        targets = self.targets
        repeated = sorted({t for t in targets if targets.count(t) > 1})
        if repeated:
            raise ValueError(f"target(s) repeated: {', '.join(repeated)}")
        reserved = sorted(set(targets) & RESERVED_NAMES)
        if reserved:  # monitor/<target> would be another topic's key (contract section 2)
            raise ValueError(f"{', '.join(reserved)} is never a target's name (monitor/{reserved[0]} "
                             "is another topic)")
        first = self.bundles[0]
        for b in self.bundles[1:]:
            if b.schedule != first.schedule or b.config != first.config:
                raise ValueError(f"targets {first.target!r} and {b.target!r} differ in schedule "
                                 "or run-time settings")

    @property
    def targets(self) -> list[str]:
        """The modelled channels, in the model's order."""
        return [b.target for b in self.bundles]

    @property
    def schedule(self) -> Schedule:
        return self.bundles[0].schedule

    @property
    def config(self) -> RuntimeConfig:
        return self.bundles[0].config

    def __getitem__(self, target: str) -> Bundle:
        for b in self.bundles:
            if b.target == target:
                return b
        raise KeyError(target)


def as_model(model: Bundle | Model) -> Model:
    """A one-target ``Model`` of a bundle; a ``Model`` as it is."""
    return model if isinstance(model, Model) else Model((model,))


def save_model(model: Bundle | Model, path: str | os.PathLike) -> Path:
    """Write a model folder: one target as a format-2 bundle, several as format 3."""
    model = as_model(model)
    if len(model.bundles) == 1:
        return save_bundle(model.bundles[0], path)
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    for b in model.bundles:
        if not _TARGET_NAME.match(b.target):
            raise ValueError(f"target {b.target!r} cannot name a sub-folder")
        save_bundle(b, out / b.target)
    manifest = {"format": FORMAT, "format_version": MULTI_VERSION,
                "created_by": f"ordervib {__version__}", "targets": model.targets}
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return out


def load_model(path: str | os.PathLike) -> Model:
    """Read and verify a model folder of any format (1 and 2: one target; 3: one or several);
    anything wrong is one OrdervibError line."""
    root = Path(path)
    manifest = _manifest(root)
    if manifest.get("format_version") != MULTI_VERSION:
        try:
            return Model((load_bundle(root),))
        except ValueError as exc:  # a reserved target name
            raise OrdervibError(f"{root}: malformed model ({exc})") from None
    targets = manifest.get("targets")
    if not (isinstance(targets, list) and targets
            and all(isinstance(t, str) and _TARGET_NAME.match(t) for t in targets)):
        raise OrdervibError(f"{root}: malformed model (targets must be a list of channel names, "
                            f"got {targets!r})")
    bundles = []
    for t in targets:
        sub = _manifest(root / t)
        if sub["format_version"] == MULTI_VERSION:
            raise OrdervibError(f"{root / t}: a target's bundle must not hold targets itself")
        b = _load_one(root / t, sub)
        if b.target != t:
            raise OrdervibError(f"{root / t}: holds target {b.target!r}, the manifest says {t!r}")
        bundles.append(b)
    try:
        return Model(tuple(bundles))
    except ValueError as exc:
        raise OrdervibError(f"{root}: malformed model ({exc})") from None


def _manifest(root: Path) -> dict:
    """The model folder's manifest, checked to be an ordervib model's of a readable format."""
    if not root.is_dir():
        raise OrdervibError(f"model bundle not found (expected a directory): {root}")
    try:
        manifest = parse_json(read_document(root / MANIFEST, str(root / MANIFEST)), str(root / MANIFEST))
    except FileNotFoundError:
        raise OrdervibError(f"{root}: no {MANIFEST}: not an ordervib model bundle") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise OrdervibError(f"{root}: not an ordervib model bundle")
    version = manifest.get("format_version")
    if version not in (*READABLE_VERSIONS, MULTI_VERSION):
        raise OrdervibError(f"{root}: bundle format version {version!r} is not supported "
                            f"(this ordervib reads versions "
                            f"{', '.join(map(str, (*READABLE_VERSIONS, MULTI_VERSION)))})")
    return manifest


def load_bundle(path: str | os.PathLike) -> Bundle:
    """Read and verify a one-target bundle (a format-3 folder: only if it holds one target);
    anything wrong is one OrdervibError line."""
    root = Path(path)
    manifest = _manifest(root)
    if manifest["format_version"] == MULTI_VERSION:
        model = load_model(root)
        if len(model.bundles) > 1:
            raise OrdervibError(f"{root}: holds {len(model.bundles)} targets "
                                f"({', '.join(model.targets)}); one is expected here")
        return model.bundles[0]
    return _load_one(root, manifest)


def _load_one(root: Path, manifest: dict) -> Bundle:
    """The bundle of format 1 or 2 at ``root``, of manifest ``manifest`` (read by ``_manifest``)."""
    try:
        data = read_bounded(root / ARRAYS, str(root / ARRAYS), MAX_ARRAYS_BYTES + NPZ_OVERHEAD)
    except FileNotFoundError:
        raise OrdervibError(f"{root}: {ARRAYS} is missing") from None
    if hashlib.sha256(data).hexdigest() != manifest.get("arrays_sha256"):
        raise OrdervibError(f"{root}: {ARRAYS} does not match the manifest's hash "
                            "(corrupted or modified bundle)")
    try:
        expected = _expected_arrays(manifest)
    except (KeyError, TypeError, ValueError) as exc:
        raise OrdervibError(f"{root}: malformed bundle ({exc!r})") from None
    arrays = read_npz(data, str(root / ARRAYS), expected, MAX_ARRAY_ELEMENTS, MAX_ARRAYS_BYTES)
    try:
        schedule = Schedule.from_dict(manifest["schedule"], f"{root} schedule")
        ocs = []
        for d in manifest["ocs"]:
            model = None
            if d["model"] is not None:
                mine = {k.split("/", 1)[1]: v for k, v in arrays.items()
                        if k.split("/", 1)[0] == d["name"]}
                model = model_from_arrays(d["model"]["method"], d["params"], mine,
                                          d["model"]["repaired"])
            calib = None
            if d["residual"] is not None:
                calib = _calibration(d["name"], d["residual"])
            envelope, outside = None, None
            if d.get("envelope") is not None:  # (bundles before it had none: no envelope)
                e = d["envelope"]
                if not isinstance(e, dict):
                    raise ValueError(f"{d['name']}: envelope must be an object")
                mine = {k.split("/", 1)[1]: v for k, v in arrays.items()
                        if k.split("/", 1)[0] == f"{ENVELOPE_PREFIX}{d['name']}"}
                envelope = Envelope.from_stored(e, mine)
                if list(envelope.inputs) != list(d["inputs"]):
                    raise ValueError(f"{d['name']}: the envelope's inputs are not the model's")
                cv = e.get("cv_outside")
                if isinstance(cv, dict):
                    outside = (float(cv["sum_z2"]), int(cv["samples"]))
            plateau = None  # (bundles before it had none: the model as it is)
            if d.get("plateau") is not None:
                plateau = PlateauShift.from_dict(d["plateau"], len(schedule.names))
            settle = SettleAnchor.from_dict(d["settle"]) if d.get("settle") is not None else None
            ocs.append(OCResult(d["name"], model, list(d["inputs"]), dict(d["params"]), d["n_runs"],
                                _f(d["train_eps"]), _f(d["cv_eps"]), calib,
                                [(c, _f(s)) for c, s in d.get("ranking", [])], [], d.get("note", ""),
                                envelope, outside, plateau, settle))
        curve = None
        if "curve/speed" in arrays:
            curve = (arrays["curve/speed"], arrays["curve/mean"])
        if curve is None and any(RUN_CURVE in r.inputs for r in ocs):
            raise ValueError(f"an OC takes {RUN_CURVE!r} but the bundle has no characteristic curve")
        config = _config(root, manifest)
        transients = None  # bundles before them kept none: no expected speed, no transient alarm
        if manifest.get("transients") is not None:
            transients = FleetTransients.from_manifest(manifest["transients"])
        forecast = None  # bundles before it kept none (or of another version): no forecast
        if manifest.get("forecast") is not None:
            forecast = PeakTable.from_manifest(manifest["forecast"], schedule.segments)
        return Bundle(manifest["method"], manifest["target"], schedule, ocs,
                      config, manifest.get("training", {}), curve,
                      _checks(manifest.get("checks", {})), transients, forecast)
    except (KeyError, TypeError, ValueError) as exc:
        raise OrdervibError(f"{root}: malformed bundle ({exc!r})") from None


def _config(root: Path, manifest: dict) -> RuntimeConfig:
    """The bundle's run-time settings; a setting out of its range is one line naming the bundle
    and the setting."""
    try:
        if manifest["format_version"] == 1:  # written before the settings were stored: that code's
            return RuntimeConfig(**V1_SETTINGS, **BEFORE_GUARD, history_s=manifest["history_s"])
        return RuntimeConfig.from_dict(manifest["runtime"], **BEFORE_GUARD)
    except SettingError as exc:
        raise OrdervibError(f"{root}: {exc}") from None


def _expected_arrays(manifest: dict) -> Callable[[str], bool]:
    """Which array names the manifest's OCs and curve account for: "<OC>/<name>" of an OC with
    a model, "envelope:<OC>/<low|high|mean|whiten>" of an OC, and the characteristic curve."""
    ocs = manifest["ocs"]
    if not isinstance(ocs, list) or not all(isinstance(d, dict) and isinstance(d["name"], str)
                                            for d in ocs):
        raise ValueError("ocs must be a list of objects with a name")
    modelled = {d["name"] for d in ocs if d.get("model") is not None}
    names = {d["name"] for d in ocs}

    def expected(key: str) -> bool:
        owner, _, name = key.partition("/")
        if owner.startswith(ENVELOPE_PREFIX):
            return owner.removeprefix(ENVELOPE_PREFIX) in names and name in ENVELOPE_ARRAYS
        return (owner in modelled and name != "") or key in CURVE_ARRAYS

    return expected


NUMERIC_CHECKS = ("flatline_samples", "step_threshold", "run_scale_prior_ocs", "residual_cv_undercoverage",
                  "vector_step_threshold", "vector_drift_threshold")


MAX_PERSIST = 600 * 40  # samples: an on-delay beyond 10 min never raises within a plateau
MAX_PEAKS = 100_000  # CV segments' peaks a calibration keeps at most


def _calibration(oc: str, c: object) -> Calibration:
    """An OC's stored residual rule, each number within its range (a ``ValueError`` naming the
    OC and the field): sigma a positive finite number (target unit), threshold positive
    (sigma units; inf: never raised), ewma_alpha in (0, 1], persist a whole number of samples
    in [1, ``MAX_PERSIST``], cv_peaks at most ``MAX_PEAKS`` finite non-negative numbers."""
    if not isinstance(c, dict):
        raise ValueError(f"{oc}: residual must be an object")

    def number(key: str, ok: Callable[[float], bool], want: str) -> float:
        v = c.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not ok(float(v)):
            raise ValueError(f"{oc}: residual.{key} must be {want}, got {v!r}")
        return float(v)

    sigma = number("sigma", lambda v: 0 < v < math.inf, "a positive finite number")
    threshold = number("threshold", lambda v: v > 0, "a positive number")
    alpha = number("ewma_alpha", lambda v: 0 < v <= 1, "in (0, 1]")
    persist = number("persist", lambda v: v == int(v) and 1 <= v <= MAX_PERSIST,
                     f"a whole number in [1, {MAX_PERSIST}]")
    peaks = c.get("cv_peaks", [])
    if not isinstance(peaks, list) or len(peaks) > MAX_PEAKS or not all(
            not isinstance(x, bool) and isinstance(x, (int, float)) and 0 <= x < math.inf for x in peaks):
        raise ValueError(f"{oc}: residual.cv_peaks must be at most {MAX_PEAKS} finite non-negative numbers")
    return Calibration(sigma, threshold, alpha, int(persist), tuple(float(x) for x in peaks))


def _checks(d: object) -> dict:
    """The model-free checks' settings; a wrong type is a malformed bundle (ValueError)."""
    if not isinstance(d, dict):
        raise ValueError(f"checks must be an object, got {type(d).__name__}")
    for key in NUMERIC_CHECKS:
        _non_negative(f"checks.{key}", d.get(key))
    per_oc = d.get("vector_drift_thresholds")
    if per_oc is not None:
        if not isinstance(per_oc, dict):
            raise ValueError(f"checks.vector_drift_thresholds must be an object, got {type(per_oc).__name__}")
        for name, v in per_oc.items():  # 0: off in that OC
            _non_negative(f"checks.vector_drift_thresholds[{name!r}]", v)
    return dict(d)


def _non_negative(what: str, v: object) -> None:
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0):
        raise ValueError(f"{what} must be a non-negative number (0: off), got {v!r}")


def _f(x: float | None) -> float:
    return float("nan") if x is None else float(x)
