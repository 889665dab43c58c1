"""Data quality: the laser noise of a record and the warnings that do not prevent a fit.

A step record that does not start at rest, one still oscillating or drifting at its end, and a set
without a static or a dynamic experiment are reported (:func:`data_warnings`), never refused.
"""
from __future__ import annotations

import numpy as np

from .data import ExperimentSet, StaticData, StepData
from .records import detrended_rms, third_difference_noise

__all__ = ["estimate_noise_m", "rest_warning", "step_settling_warning", "static_motion_warning", "data_warnings"]

#: a static point's samples spread this many times the laser noise about their trend: still moving
STATIC_MOTION_LIMIT = 1.5


def estimate_noise_m(step: StepData, min_samples: int = 20) -> float | None:
    """Laser noise sigma (m) of a sampled record, from its third differences.

    For white noise, the third difference has variance 20 sigma^2; the 10-20 Hz motion
    sampled at 1 kHz contributes (omega h)^3 ~ 1e-3 of its amplitude, so the estimate is
    insensitive to the response itself. A robust spread (1.4826 x median absolute deviation)
    ignores the few samples around the voltage step. None for fewer than ``min_samples`` samples.
    """
    return third_difference_noise(step.displacement_m, min_samples)


def rest_warning(step: StepData, noise_m: float | None) -> str | None:
    """A warning when the record does not start at rest before the step (the model assumes it does).

    The pre-step samples (detrended) should only show laser noise; a spread above 3 sigma
    (or 0.5 % of the step response) means the membrane was still moving (a previous segment
    ringing or creeping) and the fit will be biased.
    """
    k0 = step.step_index
    base = step.displacement_m[:k0]
    if base.size < 10 or noise_m is None:
        return None
    spread = detrended_rms(step.time_s[:k0], base)
    if spread > 3.0 * noise_m:
        return (
            f"{step.source}: the record does not start at rest: before the step the displacement varies by "
            f"{spread * 1e6:.3g} um RMS (noise {noise_m * 1e6:.3g} um). The model starts from the static "
            "equilibrium, so the fit is biased: let the membrane settle before the step (several "
            "eta1/k1 and the ringing) or start the record later"
        )
    return None


def step_settling_warning(step: StepData, noise_m: float | None) -> str | None:
    """A warning when the step response is still oscillating or drifting at the end of the record.

    Compares the spread of the last 20 % of the post-step record (at least 0.1 s)
    with the first window after the step; a response that keeps more than a
    quarter of its initial oscillation (and more than 3 noise sigmas) has not
    settled, and a drift over the last window extrapolating to more than 10 %
    of the step size over the record is flagged too.
    """
    t, d = step.time_s, step.displacement_m
    k0 = step.step_index
    post_t, post_d = t[k0:], d[k0:]
    if post_t.size < 20:
        return (f"{step.source}: only {post_t.size} samples after the step at {step.step_time_s:g} s; "
                "the step response cannot be judged (record a few seconds after the step)")
    duration = post_t[-1] - post_t[0]
    window = max(0.2 * duration, 0.1)
    first = post_d[post_t <= post_t[0] + window]
    last_mask = post_t >= post_t[-1] - window
    last_t, last_d = post_t[last_mask], post_d[last_mask]
    coef = np.polyfit(last_t - last_t[0], last_d, 1)
    spread_last = float(np.std(last_d - np.polyval(coef, last_t - last_t[0])))
    spread_first = float(np.std(first))
    noise = noise_m if noise_m is not None else 0.0
    baseline = d[:k0]
    step_size = abs(float(np.mean(last_d)) - float(np.mean(baseline if baseline.size else d[:1])))
    if spread_last > 0.25 * spread_first and spread_last > 3.0 * noise:
        return (
            f"{step.source}: the step response has not settled: the last {window:.2g} s still oscillate "
            f"with {spread_last * 1e6:.3g} um RMS ({100 * spread_last / max(spread_first, 1e-30):.0f} % of the "
            "first window after the step). Record longer after the step; the fit may be poor or the rig "
            "unstable (check for a growing oscillation)"
        )
    drift = abs(coef[0]) * duration
    if step_size > 0 and drift > 0.1 * step_size and drift > 3.0 * noise:
        return (
            f"{step.source}: the step response still drifts at the end of the record "
            f"({abs(coef[0]) * 1e6:.3g} um/s over the last {window:.2g} s, {100 * drift / step_size:.0f} % of "
            "the step size over the record): the slow relaxation (eta1) and the final value are poorly "
            "determined; record longer after the step"
        )
    return None


def static_motion_warning(static: StaticData, noise_m: float | None) -> str | None:
    """A warning when static points were still moving during their measurement (ringing or creeping
    after the previous level): their samples spread about their linear trend by more than
    ``STATIC_MOTION_LIMIT`` times the laser noise (third differences, which slow motion does not enter).
    Eq. 20 takes the mean as the equilibrium, so such a point biases eps_r, the stress and, through them,
    the dynamic parameters (the mock membrane after 4 s holds: eta2 +0.4 % noise-free, docs/benchmarks.md)."""
    if static.motion_rms_m is None or noise_m is None or not noise_m > 0:
        return None
    limit = STATIC_MOTION_LIMIT * noise_m
    moving = [k for k, rms in enumerate(static.motion_rms_m) if np.isfinite(rms) and rms > limit]
    if not moving:
        return None
    points = ", ".join(f"{static.voltage_V[k]:g} V at {static.mass_kg[k] * 1e3:g} g "
                       f"({static.motion_rms_m[k] * 1e6:.3g} um RMS)" for k in moving)
    return (f"{static.source}: {len(moving)} static point(s) still moving during the measurement: {points} about "
            f"their trend, laser noise {noise_m * 1e6:.3g} um. Their means are not the equilibria eq. 20 assumes, "
            "so the static and dynamic parameters are biased: hold each level longer (several of the membrane's "
            "slowest time constants, dea_ros.model.settling)")


def data_warnings(experiments: ExperimentSet) -> list[str]:
    """Data-quality warnings that do not prevent a fit (unsettled steps, missing data kinds)."""
    out = []
    noise = experiments.sensor_noise_m
    for step in experiments.steps:
        est = estimate_noise_m(step)
        sigma = noise if noise is not None else est
        for w in (rest_warning(step, sigma), step_settling_warning(step, sigma)):
            if w:
                out.append(w)
    for static in experiments.static:
        w = static_motion_warning(static, noise)
        if w:
            out.append(w)
    if not experiments.static:
        out.append("no static experiment: the static parameters (beta, gamma, eps_r) come from the base "
                   "parameters file unchanged")
    if not experiments.steps and not experiments.sines:
        out.append("no step or sine experiment: k1, eta1, eta2 are not identified")
    return out
