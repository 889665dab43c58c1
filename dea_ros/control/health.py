"""Membrane health: what changed since identification, in words, with WARN/ERROR levels (no ROS).

:class:`HealthMonitor` judges the tracked ratios of :class:`~.tracking.ModelTracker` (1 = the
identified model), the prediction error statistics (:class:`PredictionErrorStats`: measured minus
predicted displacement) and the reference against the reachable range of the tracked model. A
finding is reported once its deviation has exceeded the threshold for ``persistence_s`` (a single
noisy update raises nothing); :meth:`HealthMonitor.assess` returns a :class:`HealthReport` whose
``message`` says what changed, by how much, and the likely cause, e.g. "electrostatic gain 6 % below
the identified model: electrode ageing or a thickness change". Levels are those of
diagnostic_msgs/DiagnosticStatus (0 OK, 1 WARN, 2 ERROR).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["OK", "WARN", "ERROR", "HealthThresholds", "PredictionErrorStats", "Finding", "HealthReport",
           "HealthMonitor", "describe_drift", "describe_payload", "moving_mass_ratio"]

OK, WARN, ERROR = 0, 1, 2

#: what a tracked ratio above / below 1 likely means
CAUSES = {
    "electrostatic_gain": ("a thinner membrane or a higher permittivity (prestretch creep, humidity)",
                           "electrode ageing or a thickness change"),
    "static_stiffness": ("a stiffer membrane (cold, ageing elastomer) or a lighter payload",
                         "a softer membrane (Mullins effect, prestretch relaxation) or a heavier payload"),
    "viscoelastic_stiffness": ("a stiffer viscoelastic branch (cold elastomer)",
                               "a softer viscoelastic branch (warm elastomer)"),
    "creep_time": ("slower creep (cold elastomer)", "faster creep (warm elastomer, ageing)"),
}
LABELS = {"electrostatic_gain": "electrostatic gain", "static_stiffness": "static stiffness",
          "viscoelastic_stiffness": "viscoelastic stiffness k1", "creep_time": "creep time eta1/k1"}


@dataclass(frozen=True)
class HealthThresholds:
    """Relative deviations (fractions) and prediction errors (m) that raise WARN / ERROR."""

    warn: dict = field(default_factory=lambda: {"electrostatic_gain": 0.02, "static_stiffness": 0.02,
                                                "viscoelastic_stiffness": 0.15, "creep_time": 0.3})
    error: dict = field(default_factory=lambda: {"electrostatic_gain": 0.10, "static_stiffness": 0.10,
                                                 "viscoelastic_stiffness": 0.40, "creep_time": 0.6})
    # the gain and the static stiffness moved together (within this of each other, same direction, both
    # beyond WARN): reported as one change of the moving mass (see :func:`describe_payload`)
    payload_agreement: float = 0.01
    prediction_rms_warn_m: float = 5e-6
    prediction_rms_error_m: float = 20e-6
    persistence_s: float = 3.0

    @classmethod
    def scaled(cls, warn_scale: float = 1.0, error_scale: float = 1.0, **fields) -> "HealthThresholds":
        """The defaults with every ratio threshold multiplied (node parameters ``health_warn_scale`` ...)."""
        base = cls()
        return cls(warn={k: v * warn_scale for k, v in base.warn.items()},
                   error={k: v * error_scale for k, v in base.error.items()}, **fields)


class PredictionErrorStats:
    """Measured minus predicted displacement over a window (cleared by the caller at each report), m."""

    def __init__(self):
        self.clear()

    def clear(self) -> None:
        self.n = 0
        self.total = self.total_sq = self.max_abs = 0.0

    def add(self, measured_m: float, predicted_m: float) -> None:
        e = float(measured_m) - float(predicted_m)
        if not math.isfinite(e):
            return
        self.n += 1
        self.total += e
        self.total_sq += e * e
        self.max_abs = max(self.max_abs, abs(e))

    @property
    def mean_m(self) -> float:
        return self.total / self.n if self.n else math.nan

    @property
    def rms_m(self) -> float:
        return math.sqrt(self.total_sq / self.n) if self.n else math.nan


@dataclass(frozen=True)
class Finding:
    key: str
    level: int
    text: str


@dataclass
class HealthReport:
    """The verdict: level (0/1/2), one message, the findings, and key/value pairs for /diagnostics."""

    level: int
    message: str
    findings: list
    values: list


def describe_drift(key: str, ratio: float) -> str:
    """E.g. "electrostatic gain 6 % below the identified model: electrode ageing or a thickness change"."""
    pct = abs(ratio - 1.0) * 100.0
    above = ratio > 1.0
    cause = CAUSES[key][0 if above else 1]
    if key == "creep_time":
        how = f"{pct:.0f} % {'longer' if above else 'shorter'} than identified"
    else:
        how = f"{pct:.0f} % {'above' if above else 'below'} the identified model"
    return f"{LABELS[key]} {how}: {cause}"


def moving_mass_ratio(ratios: dict) -> float:
    """The moving mass / the identified one that the tracked gain and static stiffness stand for.

    Eq. 5 (and the dynamics, eq. 18) depend on the mass only through the stresses divided by m:
    ``d'' = g - (c1bar / m)(d / s)(sigma_Maxwell + sigma_h + sigma_1 + sigma_2)``. A payload m x r is
    exactly the identified mass with every stress x 1/r (eta2's included), in the static balance and
    in the inertia alike: no record of voltage and displacement separates the two, so the tracker
    estimates the stresses and a heavier payload reads as the gain and the static stiffness lower by
    the same factor. This is that factor's inverse (the mean of the two ratios).
    """
    return 2.0 / (ratios["electrostatic_gain"] + ratios["static_stiffness"])


def describe_payload(mass_ratio: float) -> str:
    """E.g. "moving mass 10 % above the identified model: payload changed (...)"."""
    pct = abs(mass_ratio - 1.0) * 100.0
    return (f"moving mass {pct:.0f} % {'above' if mass_ratio > 1.0 else 'below'} the identified model: payload "
            f"changed (or the gain and the stiffness {'fell' if mass_ratio > 1.0 else 'rose'} together: the force "
            "balance cannot tell them apart)")


class HealthMonitor:
    """Turns tracked ratios, prediction errors and the reachable range into findings (with persistence)."""

    def __init__(self, thresholds: HealthThresholds | None = None):
        self.thresholds = thresholds or HealthThresholds()
        self.since: dict = {}          # key -> time the deviation first exceeded its WARN threshold

    def _persistent(self, key: str, exceeded: bool, t_s: float) -> bool:
        if not exceeded:
            self.since.pop(key, None)
            return False
        start = self.since.setdefault(key, t_s)
        return t_s - start >= self.thresholds.persistence_s

    def assess(self, t_s: float, ratios: dict | None = None, prediction: PredictionErrorStats | None = None,
               reference_m: float | None = None, reachable_m: tuple | None = None) -> HealthReport:
        th = self.thresholds
        findings, values = [], []
        for key, ratio in (ratios or {}).items():
            dev = abs(ratio - 1.0)
            values.append((f"tracked_{key}_ratio", f"{ratio:.4f}"))
            if self._persistent(key, dev > th.warn[key], t_s):
                level = ERROR if dev > th.error[key] else WARN
                findings.append(Finding(key, level, describe_drift(key, ratio)))
        if ratios and "electrostatic_gain" in ratios and "static_stiffness" in ratios:
            findings = self._payload(ratios, findings, values)
        if prediction is not None and prediction.n:
            rms = prediction.rms_m
            values += [("prediction_error_mean_m", f"{prediction.mean_m:.3e}"),
                       ("prediction_error_rms_m", f"{rms:.3e}"),
                       ("prediction_error_max_m", f"{prediction.max_abs:.3e}"),
                       ("prediction_samples", str(prediction.n))]
            if self._persistent("prediction", rms > th.prediction_rms_warn_m, t_s):
                level = ERROR if rms > th.prediction_rms_error_m else WARN
                findings.append(Finding("prediction", level, (
                    f"prediction error {rms * 1e6:.1f} um RMS (mean {prediction.mean_m * 1e6:+.1f} um, limit "
                    f"{th.prediction_rms_warn_m * 1e6:.1f} um): the model no longer describes the membrane")))
        if reachable_m is not None:
            lo, hi = reachable_m
            values += [("tracked_reachable_min_m", f"{lo:.9f}"), ("tracked_reachable_max_m", f"{hi:.9f}")]
            if reference_m is not None and math.isfinite(reference_m) and not lo <= reference_m <= hi:
                findings.append(Finding("range", ERROR, (
                    f"reference {reference_m * 1e6:.1f} um is outside the reachable range "
                    f"[{lo * 1e6:.1f}, {hi * 1e6:.1f}] um of the membrane as it is now")))
        level = max((f.level for f in findings), default=OK)
        message = "; ".join(f.text for f in sorted(findings, key=lambda f: -f.level)) or "membrane as identified"
        return HealthReport(level, message, findings, values)

    def _payload(self, ratios: dict, findings: list, values: list) -> list:
        """A moving-mass finding first when the gain and the static stiffness findings agree (theirs kept after it:
        the same data fit either explanation, e.g. the tracker's first seconds at few operating points)."""
        mass = moving_mass_ratio(ratios)
        values.append(("tracked_moving_mass_ratio", f"{mass:.4f}"))
        pair = [f for f in findings if f.key in ("electrostatic_gain", "static_stiffness")]
        g, h = ratios["electrostatic_gain"], ratios["static_stiffness"]
        if len(pair) < 2 or (g - 1.0) * (h - 1.0) <= 0.0 or abs(g - h) > self.thresholds.payload_agreement:
            return findings
        return [Finding("moving_mass", max(f.level for f in pair), describe_payload(mass))] + findings
