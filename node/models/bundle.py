"""Model bundles: a directory with ``manifest.json`` and ``arrays.npz``.

Nothing in a bundle executes code on load: metadata is JSON, arrays are read
with ``allow_pickle=False``. A bundle whose format, version or array hash does
not match is refused with a one-line OrdervibError.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from node import __version__
from node.contract import FS
from node.contract.errors import OrdervibError
from node.contract.schedule import Schedule
from node.models.config import V1_SETTINGS, RuntimeConfig
from node.models.ocmodel import RUN_CURVE, model_from_arrays
from node.models.result import Calibration, OCResult

FORMAT = "ordervib-model"
FORMAT_VERSION = 2  # 2: the run-time settings are stored ("runtime"); 1 is read with the defaults
READABLE_VERSIONS = (1, 2)
MANIFEST = "manifest.json"
ARRAYS = "arrays.npz"


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
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return out


def load_bundle(path: str | os.PathLike) -> Bundle:
    """Read and verify a bundle; anything wrong is one OrdervibError line."""
    root = Path(path)
    if not root.is_dir():
        raise OrdervibError(f"model bundle not found (expected a directory): {root}")
    try:
        manifest = json.loads((root / MANIFEST).read_text())
    except FileNotFoundError:
        raise OrdervibError(f"{root}: no {MANIFEST}: not an ordervib model bundle") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise OrdervibError(f"{root / MANIFEST}: not valid JSON ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise OrdervibError(f"{root}: not an ordervib model bundle")
    version = manifest.get("format_version")
    if version not in READABLE_VERSIONS:
        raise OrdervibError(f"{root}: bundle format version {version!r} is not supported "
                            f"(this ordervib reads versions {', '.join(map(str, READABLE_VERSIONS))})")
    try:
        data = (root / ARRAYS).read_bytes()
    except FileNotFoundError:
        raise OrdervibError(f"{root}: {ARRAYS} is missing") from None
    if hashlib.sha256(data).hexdigest() != manifest.get("arrays_sha256"):
        raise OrdervibError(f"{root}: {ARRAYS} does not match the manifest's hash "
                            "(corrupted or modified bundle)")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
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
                c = d["residual"]
                calib = Calibration(c["sigma"], c["threshold"], c["ewma_alpha"], c["persist"],
                                    tuple(float(x) for x in c.get("cv_peaks", [])))
            ocs.append(OCResult(d["name"], model, list(d["inputs"]), dict(d["params"]), d["n_runs"],
                                _f(d["train_eps"]), _f(d["cv_eps"]), calib,
                                [(c, _f(s)) for c, s in d.get("ranking", [])], [], d.get("note", "")))
        curve = None
        if "curve/speed" in arrays:
            curve = (arrays["curve/speed"], arrays["curve/mean"])
        if curve is None and any(RUN_CURVE in r.inputs for r in ocs):
            raise ValueError(f"an OC takes {RUN_CURVE!r} but the bundle has no characteristic curve")
        if version == 1:  # written before the settings were stored: the values of that code
            config = RuntimeConfig(**V1_SETTINGS, history_s=float(manifest["history_s"]))
        else:
            config = RuntimeConfig.from_dict(manifest["runtime"])
        return Bundle(manifest["method"], manifest["target"], schedule, ocs,
                      config, manifest.get("training", {}), curve,
                      _checks(manifest.get("checks", {})))
    except (KeyError, TypeError, ValueError) as exc:
        raise OrdervibError(f"{root}: malformed bundle ({exc!r})") from None


NUMERIC_CHECKS = ("flatline_samples", "step_threshold", "run_scale_prior_ocs", "residual_cv_undercoverage")


def _checks(d: object) -> dict:
    """The model-free checks' settings; a wrong type is a malformed bundle (ValueError)."""
    if not isinstance(d, dict):
        raise ValueError(f"checks must be an object, got {type(d).__name__}")
    for key in NUMERIC_CHECKS:
        v = d.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0):
            raise ValueError(f"checks.{key} must be a non-negative number (0: off), got {v!r}")
    return dict(d)


def _f(x: float | None) -> float:
    return float("nan") if x is None else float(x)
