"""Figures of the prediction for a planned run (the toolbox's panel IV; matplotlib Figures on
no canvas, no pyplot, no file I/O: ``replay.views.phase_plots.save_png`` writes one).

- ``fig_prediction``: the speed profile on top (the channels filled from training runs named),
  then per target the expected amplitude over the profile, one line per stated history with
  its interval as a band and the upper bound dotted, crosses where the model's inputs left
  its training region (``envelope`` above 1), where the bounds acted in the title, the
  OCs shaded and named; with a recorded run (``RecordedPrediction``) its measured amplitude
  beside, eps_td per OC in the titles.
- ``fig_history``: figure A.5: (a) the speed profiles, (b) the cumulative energy parameter
  ς (``hist_energy``), (c) the cumulative rate of change of speed ξ (``hist_rate``), one line
  per prediction (profile or stated history).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from node.runtime.history import HISTORY_CHANNELS
from node.training.prediction import CAPPED, MEAN_MODULUS, MODULUS, RAISED, Prediction, RecordedPrediction
from replay.views.style import LABEL, SMALL

MEASURED = "0.35"  # grey: what a recorded run measured


def _minutes(p: Prediction) -> np.ndarray:
    """Time since the profile's start, min (gaps between engine runs kept)."""
    return (p.t - p.t[0]) / 60.0


def _shade_ocs(ax: Axes, p: Prediction, label: bool) -> None:
    """Alternate grey bands over the OCs of the profile, named at the top when ``label``."""
    x = _minutes(p)
    change = np.flatnonzero(np.diff(p.oc) != 0) + 1
    for n, (lo, hi) in enumerate(zip(np.r_[0, change], np.r_[change, p.oc.size])):
        oc = int(p.oc[lo])
        if oc < 0:
            continue
        ax.axvspan(x[lo], x[hi - 1], color="0.9" if n % 2 else "0.82", lw=0, zorder=0)
        if label:
            ax.text((x[lo] + x[hi - 1]) / 2, 1.01, p.oc_names[oc], transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=SMALL, rotation=90)


def _label(p: Prediction, i: int) -> str:
    return p.label or f"prediction {i + 1}"


def fig_prediction(preds: Sequence[Prediction] | RecordedPrediction, unit: str = "mm/s") -> Figure:
    """The expected amplitude of each target over the profile (see the module).

    preds: predictions over the same profile (one per stated history), or one recorded run's
    prediction against its measurement."""
    recorded = preds if isinstance(preds, RecordedPrediction) else None
    ps = [preds.prediction] if isinstance(preds, RecordedPrediction) else list(preds)
    if not ps:
        raise ValueError("no prediction to draw")
    first = ps[0]
    n = len(first.targets)
    fig = Figure(figsize=(11, 2.0 + 2.3 * n), layout="constrained")
    axes = fig.subplots(n + 1, 1, sharex=True, squeeze=False)[:, 0]
    ax = axes[0]
    _shade_ocs(ax, first, label=True)
    ax.plot(_minutes(first), first.speed, color="black", lw=1.0)
    ax.set_ylabel(f"{first.switch} (rpm)")
    if first.filled:
        ax.set_title(f"filled from training runs at the planned {first.switch} in each OC: "
                     f"{', '.join(first.filled)}", fontsize=SMALL, loc="left", pad=32)
    for j, (ax, tg) in enumerate(zip(axes[1:], first.targets)):
        _shade_ocs(ax, first, label=False)
        if recorded is not None:
            ax.plot(_minutes(first), recorded.measured[:, j], color=MEASURED, lw=0.7, label="measured")
            eps = recorded.eps[j]
            ok = np.isfinite(eps)
            if ok.any():
                ax.set_title(f"{tg}: eps_td per OC, mean {np.mean(eps[ok]):.3f} over {int(ok.sum())} OCs",
                             fontsize=LABEL, loc="left")
        for i, p in enumerate(ps):
            x = _minutes(p)
            line, = ax.plot(x, p.predicted[:, j], lw=1.1, label=f"predicted ({_label(p, i)})"
                            if recorded is None else "predicted")
            pct = f"{100 * p.level:g} %"
            ax.fill_between(x, p.lo[:, j], p.hi[:, j], color=line.get_color(), alpha=0.2, lw=0,
                            label=f"{pct} interval" if i == 0 else None)
            if i == 0 and np.isfinite(p.upper[:, j]).any():
                ax.plot(x, p.upper[:, j], color="0.4", lw=0.6, ls=":", label="bound")
            out = p.outside()[:, j]
            if out.any():  # where the model's inputs (the history among them) left its training region
                ax.plot(x[out], p.predicted[out, j], ls="none", marker="x", ms=3, color=line.get_color(),
                        label="outside the training region (envelope > 1)" if i == 0 else None)
        if recorded is None:
            acted = _acted(ps, j)
            if acted:
                ax.set_title(f"{tg}: {acted}", fontsize=SMALL, loc="left")
        ax.set_ylabel(f"{tg} ({unit})")
        ax.legend(fontsize=SMALL, loc="upper left")
    axes[-1].set_xlabel("time since the profile's start (min)")
    return fig


def _acted(ps: Sequence[Prediction], j: int) -> str:
    """Where the bounds acted on target j, over every prediction: "" when nowhere."""
    words = ((RAISED, "raised to 0"), (MODULUS, "modulus of the 1x vector"),
             (MEAN_MODULUS, "the fleet's mean amplitude for a 1x-vector model"),
             (CAPPED, "capped at the bound"))
    parts = []
    for code, what in words:
        n = sum(int(np.sum(p.bounded[:, j] == code)) for p in ps)
        if n:
            parts.append(f"{what} on {n} samples")
    return "bounds acted: " + ", ".join(parts) if parts else ""


def fig_history(preds: Sequence[Prediction]) -> Figure:
    """Figure A.5: speed profiles (a), ς = hist_energy (b), ξ = hist_rate (c), one line each."""
    if not preds:
        raise ValueError("no prediction to draw")
    fig = Figure(figsize=(9, 7.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    energy, rate = HISTORY_CHANNELS.index("hist_energy"), HISTORY_CHANNELS.index("hist_rate")
    for i, p in enumerate(preds):
        x = _minutes(p)
        line, = axes[0].plot(x, p.speed, lw=1.0, label=_label(p, i))
        axes[1].plot(x, p.history[:, energy], lw=1.2, color=line.get_color())
        axes[2].plot(x, p.history[:, rate], lw=1.2, color=line.get_color())
    axes[0].set_ylabel(f"{preds[0].switch} (rpm)")
    axes[0].set_title("(a) speed profile", fontsize=LABEL, loc="left")
    axes[0].legend(fontsize=SMALL)
    axes[1].set_ylabel("ς (rpm min)")
    axes[1].set_title("(b) cumulative energy parameter ς, corrected for the shutdown time", fontsize=LABEL,
                      loc="left")
    axes[2].set_ylabel("ξ (rpm)")
    axes[2].set_title("(c) cumulative rate of change of speed ξ", fontsize=LABEL, loc="left")
    axes[2].set_xlabel("time since the profile's start (min)")
    return fig
