"""What holds of each parameter when the model is wrong: leave-one-regime-out fits.

A model that misses an effect fits each kind of recording (step response, sine,
scanning and stepping sawtooths per direction) with a different compromise, so its
parameters move when one kind is left out; a right model's do not, beyond their
standard errors. The joint fit is repeated once per regime with that regime's
recordings left out, starting from the full fit, each parameter free only where the
remaining recordings determine it (:func:`~.informative.assess`). Over the ``K`` fits
that freed a parameter its spread is the delete-a-group jackknife's standard error,

    s = √((K − 1)/K · Σ_k (θ_k − θ̄)²),

which estimates the estimator's spread from the data's own groups, whatever the
model's error (Efron & Tibshirani 1993, §11; it needs no model of the residual). With
fewer than two fits a parameter has no spread.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .dataset import classify_regime


@dataclass(frozen=True)
class LeftOut:
    """One leave-one-regime-out fit."""

    regime: str
    recordings: tuple[str, ...]
    """The recordings left out."""
    values: dict[str, float]
    """Label → value of what this fit freed."""
    converged: bool
    message: str


@dataclass(frozen=True)
class RegimeSpread:
    """Result of :func:`regime_spread`."""

    fits: tuple[LeftOut, ...]
    spread: dict[str, float | None]
    """Label → jackknife standard error over the fits that freed it (None: fewer than
    two)."""

    def as_dict(self) -> dict:
        """For fit.json."""
        return {"method": "delete-a-regime jackknife over leave-one-regime-out joint fits",
                "spread": dict(self.spread),
                "fits": [{"left_out": f.regime, "recordings": list(f.recordings),
                          "converged": f.converged, "message": f.message,
                          "values": dict(f.values)} for f in self.fits]}


def jackknife_spread(values: Sequence[float]) -> float | None:
    """Delete-a-group jackknife standard error of ``values`` (one per left-out group),
    or None with fewer than two."""
    v = np.asarray(values, dtype=float)
    if v.size < 2:
        return None
    return float(np.sqrt((v.size - 1) / v.size * np.sum((v - v.mean()) ** 2)))


def regimes_of(recordings, q=None) -> dict[str, list[int]]:
    """Regime → indices of its recordings (:func:`~.dataset.classify_regime`)."""
    out: dict[str, list[int]] = {}
    for b, rec in enumerate(recordings):
        out.setdefault(classify_regime(rec, None if q is None else q[b]), []).append(b)
    return out


Refit = Callable[[list[int], list[str]], tuple[dict[str, float], bool, str]]
"""``refit(rows, free)`` → (label → value, converged, message): the joint fit on the
recordings ``rows`` with ``free`` the names it may move."""


def regime_spread(recordings, free: Sequence[str], refit: Refit,
                  undetermined: Callable[[list], Sequence[str]],
                  say: Callable[[str], None] = lambda s: None) -> RegimeSpread | None:
    """The leave-one-regime-out fits and each parameter's spread over them (module
    docstring); None when the recordings hold a single regime. ``free`` the full
    fit's free names; ``undetermined(recordings)`` the names a subset cannot
    determine (held in its fit)."""
    groups = regimes_of(recordings)
    if len(groups) < 2:
        return None
    fits = []
    for regime, left in groups.items():
        rows = [b for b in range(len(recordings)) if b not in left]
        held = set(undetermined([recordings[b] for b in rows]))
        names = [n for n in free if n not in held]
        say(f"[spread] without the {regime} recording(s) ({len(left)}): {len(rows)} "
            f"recording(s), free: {', '.join(names) or 'nothing'}")
        if not names:
            continue
        values, ok, message = refit(rows, names)
        fits.append(LeftOut(regime, tuple(recordings[b].name for b in left), values, ok,
                            message))
    labels = list(dict.fromkeys(lab for f in fits for lab in f.values))
    spread = {lab: jackknife_spread([f.values[lab] for f in fits if lab in f.values])
              for lab in labels}
    return RegimeSpread(tuple(fits), spread)
