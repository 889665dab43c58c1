"""What every sine record shows and what it is fitted with: the classification of the records.

Each sine record is classified twice: what the record shows from its samples (periodic at T/2,
period-doubled, quasi-periodic, not settled; :meth:`~dea_ros.identify.experiments.SineSeries.classify`)
and what the model at the current parameters realises there
(:func:`~dea_ros.solvers.sweep.frequency_sweep`: the branch a slow upward sweep is on, the
period-doubled branch in a period-doubling band, quasi-periodic in a torus band; with coexisting
responses the one nearest the measured RMS). Each record is then fitted with the matching periodic
solution (the T/2 orbit or a period-doubled one) or left out, with the reason. The sweep is of the
nominal sine; the fit solves each record with its applied waveform (a rig's record: the amplifier's
held samples), so the chosen branch is followed to that waveform (:func:`follow_applied_waveforms`):
next to a fold the held input's branch can end below the record's frequency while the sine's still
reaches it (F12, F13 of the coverage family: the joint refinement failed at its start), and such a
record is left out of this round like one beyond a fold.

:func:`classify_records` returns one dict per record (serialised in result.json without ``guess``);
:func:`fitted_points` turns the fitted ones into the frequency points of the joint refinement.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ContinuationError, HarmonicBalanceError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.collocation import periodic_interpolation_matrix, response_layout
from ..solvers.sweep import frequency_sweep
from ..solvers.sweep_results import PRIMARY
from ..solvers.inputs import SinePeriodic
from .experiments import ExperimentSet
from .frequency_points import FrequencyPoint, point_solution

__all__ = ["classify_records", "record_kinds", "branch_kind", "fitted_points", "classification_kinds",
           "leave_out_unreproduced",
           "follow_applied_waveforms", "guess_for_waveform", "leave_out_for_a_round", "sweep_for"]


def sweep_for(params: MembraneParameters, amplitude_V: float, freqs, n_harmonics: int, realised: bool = True,
              offset_V: float = 0.0):
    """The continuation sweep of the model at ``amplitude_V`` (and ``offset_V``: u = offset + U sin) over
    ``freqs`` (Hz; sorted, unique)."""
    return frequency_sweep(params, SinePeriodic(amplitude_V, 1.0, offset_V), np.unique(np.asarray(freqs, float)),
                           n_harmonics=n_harmonics, realised=realised)


def branch_kind(name: str) -> str:
    """The response kind of a continuation branch: the primary T/2 orbit or a period-doubled one."""
    return "T/2 orbit" if name == PRIMARY else "period-doubled (T)"


def record_kinds(experiments: ExperimentSet, noise_m: float | None) -> dict:
    """What the sampled records show from the data alone, before any fit: (source, f rounded) -> kind."""
    kinds = {}
    for sine in experiments.sines:
        for ser in sine.series:
            kinds[(sine.source, round(ser.frequency_Hz, 9))] = ser.classify(noise_m)["kind"]
    return kinds


def _candidates(sweep, f: float) -> list:
    """(branch name, SweepPoint) of every periodic solution at f (none without a sweep)."""
    if sweep is None:
        return []
    return [(b.name, p) for b in sweep.branches for p in b.points if abs(p.frequency_Hz - f) <= 1e-9 * max(f, 1.0)]


def _group_sweep(params: MembraneParameters, amplitude_V: float, offset_V: float, freqs, n_harmonics: int) -> tuple:
    """(sweep, '') of one excitation's records (the kinds only), or (None, why) when the model's response cannot be
    computed. A sweep whose first frequency does not solve or whose continuation stalls (next to a fold: a planned
    second pass's records sit at the resonance peak) starts again at half of it, from below, as a slow upward sweep
    reaches the records."""
    freqs = np.asarray(freqs, float)
    try:
        return sweep_for(params, amplitude_V, freqs, n_harmonics, realised=False, offset_V=offset_V), ""
    except (HarmonicBalanceError, ContinuationError):
        pass
    try:
        return sweep_for(params, amplitude_V, np.r_[0.5 * freqs.min(), freqs], n_harmonics, realised=False,
                         offset_V=offset_V), ""
    except (HarmonicBalanceError, ContinuationError) as exc:
        what = f"{amplitude_V:g} V" + (f" + {offset_V:g} V offset" if offset_V else "")
        return None, (f"the model's response to {what} could not be computed ({str(exc)[:160]}); classified again "
                      "after the next round of the fit")


def _choose(data_kind, model_kind, cands: list, stable: list, meas: float, f: float) -> tuple:
    """(branch name, SweepPoint) the record is fitted with, or None, and the reason when None."""
    def pick(primary: bool, pool):
        # the T/2 branch by its exact name, or any period-doubled one (never a substring match:
        # "T" is in "T/2")
        cand = [(n, pt) for n, pt in pool if (n == PRIMARY) == primary]
        return min(cand, key=lambda c: abs(c[1].d_rms_m - meas)) if cand else None

    want = data_kind or model_kind
    chosen, reason = None, ""
    if want == "quasi-periodic":
        reason = ("the record is quasi-periodic (no period in its samples)" if data_kind else
                  "the model has no stable periodic response there (quasi-periodic: a torus band)")
    elif want == "period-doubled":
        chosen = pick(False, stable) or pick(False, cands)
        if chosen is None:
            reason = ("the record is period-doubled but the model has no period-doubled orbit at "
                      f"{f:g} Hz with the current parameters")
    elif want in ("periodic", "coexisting"):
        pool = stable or cands
        if data_kind == "periodic":
            chosen = pick(True, pool) or pick(True, cands)
        else:
            chosen = min(pool, key=lambda c: abs(c[1].d_rms_m - meas)) if pool else None
        if chosen is None:
            reason = "no periodic solution of the model there"
    else:
        reason = "the model response could not be computed"
    return chosen, reason


def _mark_fitted(entry: dict, chosen: tuple, stable: list) -> None:
    """``entry`` fitted on the branch ``chosen``, with notes where data and model disagree or coexist."""
    name, pt = chosen
    data_kind, model_kind, meas = entry["data_kind"], entry["model_kind"], entry["measured_rms_m"]
    entry["used"] = "periodic" if name == PRIMARY else "period-doubled"
    entry["branch"] = name
    entry["guess"] = pt.solution.state
    entry["fitted_model_rms_m"] = float(pt.d_rms_m)   # the RMS of the model's response on that branch
    if data_kind and model_kind and data_kind != model_kind and model_kind != "coexisting":
        entry["note"] = (f"the data show a {data_kind} response, the model at these parameters "
                         f"a {model_kind} one; fitted as {entry['used']}")
    if len(stable) > 1:
        # several stable responses: say which the data are on and what else the model has
        # (by the point, not the branch's name: one branch folding back has two stable points at f)
        entry["coexisting"] = [{"branch": n, "kind": branch_kind(n), "d_rms_m": float(q.d_rms_m),
                                "fitted": q is pt} for n, q in stable]
        others = ", ".join(f"{branch_kind(n)} {q.d_rms_m * 1e6:.4g} um" for n, q in stable
                           if q is not pt)
        entry["note"] = (f"coexisting stable responses in the model: {branch_kind(name)} "
                         f"{pt.d_rms_m * 1e6:.4g} um (fitted: the record, {meas * 1e6:.4g} um"
                         + (f", {data_kind}" if data_kind else "") + f", is on it) and {others}"
                         " (which one a measurement sees depends on the history)")


def _classify_record(sine, k: int, amplitude_V: float, sweep, responses: dict, series: dict, noise_m) -> dict:
    """The classification entry of record ``k`` of ``sine`` (see :func:`classify_records`)."""
    f = float(sine.frequency_Hz[k])
    meas = float(sine.d_rms_m[k])
    ser = series.get(round(f, 9))
    data = ser.classify(noise_m) if ser is not None else None
    data_kind = data["kind"] if data else None
    resp = responses.get(round(f, 9))
    model_kind = resp.kind if resp is not None else None
    cands = _candidates(sweep, f)
    stable = [(n, pt) for n, pt in cands if pt.stable]
    entry = {"frequency_Hz": f, "amplitude_V": float(amplitude_V), "source": sine.source, "index": int(k),
             "measured_rms_m": meas, "data_kind": data_kind, "model_kind": model_kind,
             "model_rms_m": resp.d_rms_m if resp is not None else None}
    if data:
        entry["data_test"] = {kk: v for kk, v in data.items() if kk != "kind"}
    chosen, reason = _choose(data_kind, model_kind, cands, stable, meas, f)
    if chosen is not None:
        _mark_fitted(entry, chosen, stable)
    else:
        entry["used"] = "left out"
        entry["reason"] = reason
    return entry


def classify_records(params: MembraneParameters, experiments: ExperimentSet, n_harmonics: int = 8,
                     noise_m: float | None = None) -> list:
    """What every sine record shows and what it is fitted with (module docstring).

    One dict per record: frequency_Hz, amplitude_V, source, measured_rms_m, ``data_kind`` (from the
    sampled record, None without one), ``model_kind`` (the realised response of the model),
    ``used`` ("periodic", "period-doubled" or "left out"), ``reason``, and ``guess`` (a state on
    the branch to fit; not serialised).
    """
    out = []
    for sine in experiments.sines:
        p = params.replace(mass_kg=sine.mass_kg)
        series_by_f = {round(s.frequency_Hz, 9): s for s in sine.series}
        for a, offset, sel in sine.waveform_groups():
            sweep, failure = _group_sweep(p, a, offset, sine.frequency_Hz[sel], n_harmonics)
            by_f = {} if sweep is None else {round(r.frequency_Hz, 9): r for r in sweep.responses}
            for k in sel:
                entry = _classify_record(sine, k, a, sweep, by_f, series_by_f, noise_m)
                if failure:
                    entry["used"], entry["reason"] = "left out", failure
                if offset:
                    entry["offset_V"] = offset
                out.append(entry)
    follow_applied_waveforms(out, params, experiments, n_harmonics)
    leave_out_unreproduced(out)
    return out


#: A fitted record whose response to its applied waveform differs from the chosen branch's response to
#: the nominal sine by more than this share (d_rms) has been solved on another branch.
APPLIED_BRANCH_TOLERANCE = 0.1


def guess_for_waveform(state: np.ndarray, waveform, n_harmonics: int, samples: int = 256,
                       offset: bool = False) -> np.ndarray:
    """The nominal sine's T/2 orbit ``state`` (3, M) as a seed for ``waveform`` (an applied periodic input):
    moved to the waveform's phase (a record starts at its own phase: the 2f component of u^2 locates it)
    and laid out over the waveform's response period (the full period T when its u^2 is not T/2-periodic).
    Without it Newton started a half-cycle off next to a fold and failed (F13 of the coverage family,
    7.944 Hz: phase 1.13 rad; aligned it solves on the record's branch, 1011.10 um for 1011.09 measured).
    ``offset``: ``state`` is the nominal offset sine's orbit, over T; the f component of u locates the phase."""
    theta = 2.0 * np.pi * np.arange(samples) / samples
    u = np.asarray(waveform.at_phase(theta), float)
    divisor, m = response_layout(waveform, n_harmonics, True)
    phases = 2.0 * np.pi * np.arange(m) / (m * divisor)           # over T
    state = np.asarray(state, float)
    if offset:      # u(theta) ~ offset + U sin(theta + shift): the f coefficient of sin is 1/(2i)
        shift = float(np.angle(np.sum(u * np.exp(-1j * theta)))) + 0.5 * np.pi
        return state @ periodic_interpolation_matrix(state.shape[1], np.mod(phases + shift, 2.0 * np.pi)).T
    c2 = np.sum(u ** 2 * np.exp(-2j * theta))
    shift = 0.5 * float(np.angle(-c2))     # u(theta) ~ U sin(theta + shift): sin^2's 2f coefficient is -1/4
    return state @ periodic_interpolation_matrix(state.shape[1], np.mod(2.0 * (phases + shift), 2.0 * np.pi)).T


def follow_applied_waveforms(entries: list, params: MembraneParameters, experiments: ExperimentSet,
                             n_harmonics: int) -> None:
    """Each fitted record that has an applied waveform solved with it as the fit solves it
    (:func:`~dea_ros.identify.frequency_points.point_solution` from the chosen branch's state, moved to the
    waveform's phase and period by :func:`guess_for_waveform`): the solution becomes the record's
    ``guess``. Where it does not solve (the branch of the applied waveform folds below the record's
    frequency) or lands on another branch (d_rms off by more than
    :data:`APPLIED_BRANCH_TOLERANCE`), the record is left out of this round with the reason."""
    for e, pt in zip(entries, _points(entries, experiments)):
        if pt is None or pt.periodic_input is None:
            continue
        if pt.kind == "periodic" and pt.guess is not None:
            pt = dataclasses.replace(pt, guess=guess_for_waveform(pt.guess, pt.periodic_input, n_harmonics,
                                                                  offset=bool(e.get("offset_V"))))
        p = params.replace(mass_kg=pt.mass_kg)
        try:
            sol = point_solution(p, pt, n_harmonics)
            rms = sol.displacement_rms(float(static_equilibrium(p, 0.0).displacement_m))
        except HarmonicBalanceError as exc:
            why = f"it does not solve ({str(exc)[:120]})"
        else:
            if abs(rms / e["fitted_model_rms_m"] - 1.0) <= APPLIED_BRANCH_TOLERANCE:
                e["guess"] = sol.state
                continue
            why = f"it lands on another response ({rms * 1e6:.4g} um)"
        leave_out_for_a_round(e, f"the model's {branch_kind(e['branch'])} at {e['fitted_model_rms_m'] * 1e6:.4g} um "
                              f"(nominal sine) followed to the record's applied waveform: {why}; next to a fold, "
                              "beyond it for that waveform at the current parameters")


#: A fitted record whose measured RMS and the nearest model response of its kind differ by more than
#: this factor is not reproduced by the model at the current parameters (see leave_out_unreproduced).
UNREPRODUCED_RATIO = 2.0
#: ... and is left out only while such records are at most this share of the fitted ones.
UNREPRODUCED_MAX_SHARE = 0.25


def leave_out_unreproduced(entries: list) -> None:
    """Leave out the isolated records that no model response of their kind comes near (a factor
    :data:`UNREPRODUCED_RATIO` in RMS): near a jump of the resonance (a fold), the record can be on a
    branch the model at the current parameters does not have yet (its fold a little below the
    record's frequency: F07 of the coverage family, 1.73 mm measured, only the lower branch's 0.36 mm
    in the model). Fitted with the branch that exists, its residual of thousands of standard errors
    dominates the objective and drags every parameter away (eps_r +38 %, eta1 -98 %, from a two-stage
    result within 1 %). Left out, the round fits the others; the next round classifies it again at
    the refined parameters and fits it once the model reaches it. When many records are that far off,
    the parameters themselves are off: all stay in, as before."""
    fitted = [e for e in entries if e["used"] != "left out"]
    far = []
    for e in fitted:
        model_m, meas = e["fitted_model_rms_m"], e["measured_rms_m"]
        if model_m > 0 and meas > 0 and max(meas / model_m, model_m / meas) > UNREPRODUCED_RATIO:
            far.append((e, model_m))
    if not far or len(far) > UNREPRODUCED_MAX_SHARE * len(fitted):
        return
    for e, model_m in far:
        leave_out_for_a_round(e, f"no response of the model at the current parameters comes near the record "
                                 f"({e['measured_rms_m'] * 1e6:.4g} um measured, {model_m * 1e6:.4g} um on the nearest "
                                 f"{branch_kind(e['branch'])}): it is on a branch the model does not have there yet "
                                 "(beyond a fold)")


def leave_out_for_a_round(entry: dict, why: str) -> None:
    """A fitted record left out of this round of the fit, with the reason (classified again after it)."""
    entry["used"] = "left out"
    entry["reason"] = f"{why}; classified again after the next round of the fit"
    for key in ("guess", "branch", "coexisting", "note"):
        entry.pop(key, None)


def _points(classification: list, experiments: ExperimentSet) -> list:
    """The FrequencyPoint of each classified record (None where it is left out)."""
    pts = []
    for c in classification:
        if c["used"] == "left out":
            pts.append(None)
            continue
        sine = [s for s in experiments.sines if s.source == c["source"]][0]
        k = c["index"]
        pts.append(FrequencyPoint(
            c["frequency_Hz"], c["amplitude_V"], c["measured_rms_m"], sine.mass_kg, sine.source,
            None if sine.d_rms_std_m is None else float(sine.d_rms_std_m[k]),
            sine.inputs[k] if sine.inputs else None, kind=c["used"], guess=c.get("guess"), rest_d0_m=sine.rest_d0(k)))
    return pts


def fitted_points(classification: list, experiments: ExperimentSet) -> list:
    """FrequencyPoints of the classified records that are fitted (with their kind and seed)."""
    return sorted([p for p in _points(classification, experiments) if p is not None], key=lambda p: p.frequency_Hz)


def classification_kinds(classification: list) -> list:
    """(frequency, how fitted, branch) of every record: what a change of the classification compares."""
    return [(round(c["frequency_Hz"], 9), c["used"], c.get("branch")) for c in classification]
