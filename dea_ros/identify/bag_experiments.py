"""Experiments from a bag: cut static, step and sine experiments out of a recorded rig session.

Signals: the applied voltage (``sensor_msgs/msg/BatteryState`` -> ``voltage``, or
``std_msgs/msg/Float64`` -> ``data``) and the displacement (``sensor_msgs/msg/Range`` ->
``range``, or ``std_msgs/msg/Float64``; a non-finite displacement -- a sample laser_sensor_node
flagged implausible, REP 117's invalid -- is skipped). Stamped messages use their header stamp (the acquisition
time), others the bag's log time. Topic names are configurable (:class:`BagTopics`). The bag is
read with the public API of :mod:`dea_ros.bag` (:class:`~dea_ros.bag.BagReader`).

Segments: a bag recorded by identifier_node carries an MCAP metadata record
``dea_ros.experiment`` (:data:`EXPERIMENT_METADATA`) with the protocol's schedule (JSON,
:mod:`dea_ros.identify.protocols`) and its start time. For any other rosbag2 bag, give the same
information as a YAML file (``segments_file``)::

    membrane: A2          # preset or parameters YAML with the geometry
    mass_kg: 0.003
    t0_s: 1700000000.0    # absolute time of the protocol start (s); times below are relative
    segments:
      - {kind: static, voltage_V: 0, measure_start_s: 3, measure_end_s: 4}
      - {kind: step, start_s: 4, end_s: 9}
      - {kind: sine, frequency_Hz: 9.0, amplitude_V: 2500, measure_start_s: 20, measure_end_s: 23}

Static: mean displacement over the measurement window. Step: voltage (zero-order hold of the
applied voltage) and displacement at the displacement samples of the segment. Sine: RMS of
d - d0 over whole periods of the window (eq. 21), d0 = the measured rest position at 0 V
(static segment at 0 V, else the start of the recording), with the sampled series attached; the
laser noise (from the static segments) is removed from the mean square and gives each RMS its
standard uncertainty (plus, for a record whose halves differ by more than 3 sigma, that difference:
it has not settled). The fit's input is the recorded voltage held from each stamp (the
amplifier's zero-order hold).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..bag import BagReader
from ..errors import BagError, ExperimentError
from ..model.parameters import load_parameters
from .experiments import (
    GEOMETRY_FIELDS,
    ExperimentSet,
    SineData,
    SineSeries,
    StaticData,
    StepData,
    periodic_input_from_record,
    rms_statistics,
    detrended_rms,
    third_difference_noise,
)

__all__ = ["BagTopics", "BagSignals", "read_signals", "experiments_from_bag", "experiments_from_signals",
           "EXPERIMENT_METADATA"]

#: name of the MCAP metadata record written by identifier_node
EXPERIMENT_METADATA = "dea_ros.experiment"

_VALUE_FIELDS = {
    "sensor_msgs/msg/BatteryState": "voltage",
    "sensor_msgs/msg/Range": "range",
    "std_msgs/msg/Float64": "data",
    "std_msgs/msg/Float32": "data",
}


@dataclass(frozen=True)
class BagTopics:
    """The topics of the applied voltage and of the displacement."""

    voltage: str = "/dea/voltage"
    displacement: str = "/dea/displacement"


@dataclass
class BagSignals:
    """Voltage and displacement time series of a bag (s since the epoch, V, m) and its metadata records."""

    voltage_t_s: np.ndarray
    voltage_V: np.ndarray
    displacement_t_s: np.ndarray
    displacement_m: np.ndarray
    metadata: dict


# --------------------------------------------------------------------------- signals
def _resolve(topics_in_bag: dict, wanted: str, role: str, path) -> str:
    if wanted in topics_in_bag:
        return wanted
    # allow a different namespace: match on the last path element
    base = wanted.rsplit("/", 1)[-1]
    matches = [t for t in topics_in_bag if t.rsplit("/", 1)[-1] == base]
    if len(matches) == 1:
        return matches[0]
    raise BagError(
        f"{path}: no {role} topic '{wanted}' (topics: {sorted(topics_in_bag)}); "
        f"name it with --{role}-topic"
    )


def _topic_names(info: dict, topics: BagTopics, path) -> dict:
    """role -> topic name in the bag, each of a supported type and with messages."""
    names = {}
    for role, wanted in (("voltage", topics.voltage), ("displacement", topics.displacement)):
        name = _resolve(info, wanted, role, path)
        if info[name].type not in _VALUE_FIELDS:
            raise BagError(
                f"{path}: topic {name} has type {info[name].type}; the {role} must be one of "
                f"{sorted(_VALUE_FIELDS)}"
            )
        if info[name].message_count == 0:
            raise BagError(f"{path}: topic {name} ({role}) has no messages")
        names[role] = name
    return names


def read_signals(path, topics: BagTopics = BagTopics()) -> BagSignals:
    """Voltage and displacement time series (s since the epoch, V, m) and the metadata records."""
    with BagReader(path) as bag:
        info = bag.topics()
        names = _topic_names(info, topics, path)
        series = {role: ([], []) for role in names}
        role_of = {v: k for k, v in names.items()}
        for topic, log_ns, msg in bag.messages(list(names.values())):
            role = role_of[topic]
            value_field = _VALUE_FIELDS[info[topic].type]
            header = getattr(msg, "header", None)
            if header is not None:
                t = header.stamp.sec + header.stamp.nanosec * 1e-9
            else:
                t = log_ns * 1e-9
            value = float(getattr(msg, value_field))
            if role == "voltage" and hasattr(msg, "present") and not msg.present:
                value = 0.0 if not math.isfinite(value) else value
            if role == "displacement" and not math.isfinite(value):
                continue  # flagged invalid by laser_sensor_node (REP 117 NaN; the value is on displacement_implausible)
            series[role][0].append(t)
            series[role][1].append(value)
        meta = bag.metadata()
    out = {}
    for role, (t, v) in series.items():
        t, v = np.asarray(t), np.asarray(v, float)
        order = np.argsort(t, kind="stable")
        out[role] = (t[order], v[order])
    return BagSignals(out["voltage"][0], out["voltage"][1], out["displacement"][0], out["displacement"][1], meta)


def pass_metadata_name(number: int) -> str:
    """The metadata record of experiment pass ``number`` (1: :data:`EXPERIMENT_METADATA`, then ``.pass2`` ...)."""
    return EXPERIMENT_METADATA if number == 1 else f"{EXPERIMENT_METADATA}.pass{number}"


def experiment_record(protocol, segments, t0_ns: int, completed: int, aborted: bool, command_rate_hz: float,
                      membrane: str, number: int = 1, extra: dict | None = None) -> dict:
    """The metadata record of one pass as identifier_node writes it (strings; the schedule as JSON)."""
    return {
        "protocol": protocol.name, "protocol_source": str(protocol.source), "membrane": membrane,
        "mass_kg": repr(protocol.mass_kg), "t0_ns": str(t0_ns),
        "segments_json": json.dumps([s.to_dict() for s in segments]), "segments_completed": str(completed),
        "aborted": "true" if aborted else "false", "command_rate_hz": repr(command_rate_hz),
        "pass": str(number), "adaptive": "true" if protocol.adaptive else "false", **(extra or {}),
    }


def _pass_number(name: str) -> int | None:
    if name == EXPERIMENT_METADATA:
        return 1
    prefix = f"{EXPERIMENT_METADATA}.pass"
    if name.startswith(prefix) and name[len(prefix):].isdigit():
        return int(name[len(prefix):])
    return None


def experiment_passes(metadata: dict, path) -> list:
    """[(information, t0 in s since the epoch, segments)] of every pass recorded, in pass order: pass 1 is
    :data:`EXPERIMENT_METADATA`, an adaptive second pass ``dea_ros.experiment.pass2`` (each with its own t0;
    a pass aborted keeps its completed segments only)."""
    numbered = sorted((n, name) for name in metadata for n in [_pass_number(name)] if n is not None)
    if not numbered or numbered[0][0] != 1:
        raise BagError(
            f"{path}: no '{EXPERIMENT_METADATA}' metadata (not recorded by identifier_node); "
            "describe the experiments with a segments YAML (--segments FILE)"
        )
    passes = []
    for _n, name in numbered:
        record = metadata[name]
        try:
            segments = json.loads(record["segments_json"])
            t0 = int(record["t0_ns"]) * 1e-9
        except (KeyError, ValueError) as exc:
            raise BagError(f"{path}: metadata '{name}' is malformed ({exc})") from None
        if str(record.get("aborted", "false")).lower() == "true":
            segments = segments[:int(record.get("segments_completed", len(segments)))]
        passes.append(({k: v for k, v in record.items() if k != "segments_json"}, t0, segments))
    return passes


def _schedule(signals: BagSignals, segments_file, path) -> list:
    """[(information, t0 in s since the epoch, segments)] per pass, from the segments YAML (one pass) or the
    identifier's records."""
    if segments_file is not None:
        data = yaml.safe_load(Path(segments_file).read_text())
        if not isinstance(data, dict) or "segments" not in data or "t0_s" not in data:
            raise BagError(f"{segments_file}: needs 't0_s' and 'segments' (see dea_ros.identify.bag_experiments)")
        return [(data, float(data["t0_s"]), list(data["segments"]))]
    return experiment_passes(signals.metadata, path)


# --------------------------------------------------------------------------- segments
class _Timeline:
    """The signals on the protocol's time line (s from its start t0)."""

    def __init__(self, signals: BagSignals, t0: float, command_rate_hz: float):
        self.tv, self.uv = signals.voltage_t_s - t0, signals.voltage_V
        self.td, self.dd = signals.displacement_t_s - t0, signals.displacement_m
        self.command_lead_s = 2.0 / command_rate_hz

    @property
    def guard_s(self) -> float:
        """Time (s) left out before a segment's end: identifier_node commands one period ahead, so
        the next segment's voltage can appear just before the boundary."""
        return max(0.01, self.command_lead_s)

    def window(self, a, b):
        """Samples in [a, b - guard)."""
        k = (self.td >= a) & (self.td < b - self.guard_s)
        return self.td[k], self.dd[k]

    def window_of_same_input(self, a, b, input_start_s):
        """Samples of a window [a, b) as long as it was planned: moved earlier by the guard when the
        same input was already applied then (from ``input_start_s`` on, a sine's settling), so a
        record of whole periods keeps all of them; else :meth:`window`."""
        shift = self.guard_s if a - self.guard_s >= input_start_s else 0.0
        k = (self.td >= a - shift) & (self.td < b - self.guard_s)
        return self.td[k], self.dd[k]

    def voltage_at(self, t):
        """Zero-order hold of the applied voltage at times t (s, relative to t0).

        A change stamped at t_k holds from t_k on. Stamps are epoch seconds, whose float64
        resolution is ~0.2 us: without the 1 us tolerance a sample taken at the very instant of
        a change would often get the previous voltage (a one-sample, 1 ms, delay of the step).
        """
        idx = np.clip(np.searchsorted(self.tv, t + 1e-6, side="right") - 1, 0, self.tv.size - 1)
        return self.uv[idx]


@dataclass
class _Cut:
    """What the segments hold: static points, steps, sine windows and the rest position."""

    static_u: list = field(default_factory=list)
    static_d: list = field(default_factory=list)
    static_noise: list = field(default_factory=list)
    static_motion: list = field(default_factory=list)   # RMS about the linear trend of each point's window
    static_samples: list = field(default_factory=list)  # samples averaged per point
    steps: list = field(default_factory=list)
    #: (record, amplitude V, offset V, held-voltage times, held voltages) per sine segment
    sines: list = field(default_factory=list)
    rest_d0: float | None = None


def _cut_static(cut: _Cut, line: _Timeline, seg: dict, k: int, path) -> None:
    t, d = line.window(seg["measure_start_s"], seg["measure_end_s"])
    if t.size < 3:
        raise BagError(f"{path}: static segment {k} ({seg.get('voltage_V')} V) has {t.size} samples")
    u = float(np.mean(line.voltage_at(t)))
    cut.static_u.append(u)
    cut.static_d.append(float(np.mean(d)))
    cut.static_motion.append(detrended_rms(t, d))
    cut.static_samples.append(int(d.size))
    # the laser noise at a constant voltage (third differences: ringing after the change hardly enters)
    sigma = third_difference_noise(d)
    if sigma is not None:
        cut.static_noise.append(sigma)
    if abs(u) < 1.0 and cut.rest_d0 is None:
        cut.rest_d0 = float(np.mean(d))


def _cut_sine(cut: _Cut, line: _Timeline, seg: dict, k: int, path, label: str = "") -> None:
    f = float(seg["frequency_Hz"])
    start = seg.get("start_s", seg["measure_start_s"])
    t, d = line.window_of_same_input(seg["measure_start_s"], seg["measure_end_s"], start)
    if t.size < 20:
        raise BagError(f"{path}: sine segment {k} ({f} Hz) has {t.size} samples")
    s = SineSeries(f, t - t[0], line.voltage_at(t), d, source=f"{path}{label} sine {f:g} Hz", voltage_hold="zoh")
    # the applied voltage is the amplifier's recorded output, each value held from its stamp
    # until the next: its own time line (not the laser's) carries the hold exactly
    inside = (line.tv > t[0]) & (line.tv < t[-1])
    held_t = np.r_[t[0], line.tv[inside]] - t[0]
    held_u = np.r_[line.voltage_at(t[:1]), line.uv[inside]]
    cut.sines.append((s, float(seg["amplitude_V"]), float(seg.get("offset_V", 0.0)), held_t, held_u))


def _cut_segments(cut: _Cut, line: _Timeline, segments: list, mass: float, path, label: str = "") -> None:
    """Every segment of one pass's schedule cut out of the signals into ``cut`` (rest segments are skipped;
    ``label`` names the pass in the records' sources)."""
    for k, seg in enumerate(segments):
        kind = seg.get("kind")
        if kind == "static":
            _cut_static(cut, line, seg, k, path)
        elif kind == "step":
            t, d = line.window(seg["start_s"], seg["end_s"])
            if t.size < 20:
                raise BagError(f"{path}: step segment {k} has {t.size} samples")
            cut.steps.append(StepData(t - t[0], line.voltage_at(t), d, mass, source=f"{path}{label} step segment {k}"))
        elif kind == "sine":
            _cut_sine(cut, line, seg, k, path, label)
        elif kind == "rest":
            continue
        else:
            raise BagError(f"{path}: segment {k} has unknown kind {kind!r}")


def _distinct_frequencies(records: list) -> list:
    """The sine records of one waveform in groups whose frequencies differ (the first group the record's
    frequency is not yet in, within 1e-6 relative, wider than SineData's own check; the records' order kept):
    SineData holds one point per frequency."""
    groups: list = []
    for rec in records:
        f = rec[0].frequency_Hz
        target = next((g for g in groups if all(abs(r[0].frequency_Hz - f) > 1e-6 * max(f, 1.0) for r in g)), None)
        if target is None:
            groups.append([rec])
        else:
            target.append(rec)
    return groups


def _sine_data(cut: _Cut, series: list, noise: float | None, mass: float, source: str,
               measured_inputs: bool) -> SineData:
    """The frequency response of sine windows of one waveform (eq. 21, module docstring)."""
    freqs = np.array([s[0].frequency_Hz for s in series])
    amps = np.array([s[1] for s in series])
    # eq. 21 with the laser noise removed and its standard uncertainty (rms_statistics), the noise
    # from the static segments (a sine record sampled at 500 Hz moves too fast for the third
    # differences); without static segments the RMS carries no stated uncertainty. About the measured
    # rest position, which the records state (d0_m) and the fit takes the model's RMS about as well
    # (FrequencyPoint.rest_d0_m): its measurement error is in both and cancels, so neither the mean
    # square's correction nor the uncertainty counts it (counted in each record's uncertainty, one error
    # common to every record would weigh as many independent ones: issue 21, session 18)
    stats = [rms_statistics(s[0], cut.rest_d0, noise) for s in series]
    rms = np.array([v for v, _ in stats])
    std = np.array([e for _, e in stats]) if all(e is not None for _, e in stats) else None
    if std is not None:
        # a record that has not settled (its halves' d_rms differ by > 3 sigma): the difference
        # is the size of its remaining transient, an uncertainty the noise does not state
        for k, (s, *_rest) in enumerate(series):
            change, change_std = s.settling_m(cut.rest_d0, noise)
            if change_std > 0 and abs(change) > 3.0 * change_std:
                std[k] = math.hypot(std[k], change)
    # the membrane received the applied voltage (command timing, zero-order hold, slew limit),
    # not the nominal sine: fit and evaluate with the measured waveforms
    inputs = tuple(periodic_input_from_record(ht, hu, s.frequency_Hz, "zoh", source=s.source)
                   for s, _a, _o, ht, hu in series) if measured_inputs else ()
    # without offset the identifier applies |U sin| (a unipolar amplifier; protocols._sine)
    unipolar = all(o == 0.0 and np.min(s.voltage_V) >= 0.0 for s, _a, o, _t, _u in series)
    return SineData(freqs, amps, rms, mass, d0_m=np.full(freqs.size, cut.rest_d0),
                    series=tuple(s[0] for s in series), source=source, inputs=inputs,
                    d_rms_std_m=std, waveform="abs_sine" if unipolar else "sine")


def experiments_from_bag(path, topics: BagTopics = BagTopics(), segments_file=None, membrane=None,
                         measured_inputs: bool = True) -> ExperimentSet:
    """An :class:`~dea_ros.identify.experiments.ExperimentSet` cut from a bag.

    ``measured_inputs``: the sine experiments carry the applied voltage of each window as a
    periodic input (:meth:`SineSeries.measured_input`), used by the fit instead of the nominal sine.
    """
    return experiments_from_signals(read_signals(path, topics), path, segments_file, membrane, measured_inputs)


def experiments_from_signals(signals: BagSignals, path, segments_file=None, membrane=None,
                             measured_inputs: bool = True) -> ExperimentSet:
    """:func:`experiments_from_bag` of the signals a bag holds (``path`` names them in messages and
    sources): what :func:`~dea_ros.identify.synth_rig.rig_experiments` hands the same extraction."""
    passes = _schedule(signals, segments_file, path)
    info = passes[0][0]
    membrane_ref = membrane or info.get("membrane", "A2")
    base = load_parameters(membrane_ref)
    mass = float(info.get("mass_kg", base.mass_kg))
    if signals.displacement_t_s.size < 10:
        raise BagError(f"{path}: only {signals.displacement_t_s.size} displacement samples")
    cut = _Cut()
    for n, (info_n, t0_n, segments_n) in enumerate(passes, 1):   # every pass on its own time line
        line = _Timeline(signals, t0_n, float(info_n.get("command_rate_hz", 500.0)))
        _cut_segments(cut, line, segments_n, mass, path, f" pass {n}" if n > 1 else "")
        if n == 1 and cut.rest_d0 is None:  # the rest position before the first command
            td, dd = line.td, line.dd
            cut.rest_d0 = float(np.mean(dd[td < min(0.5, td[-1])])) if np.any(td < 0.5) else float(dd[0])
    # the laser noise, from the static segments (third differences at a constant voltage)
    noise = float(np.sqrt(np.mean(np.square(cut.static_noise)))) if cut.static_noise else None
    noise = noise if (noise is not None and 0.0 < noise < 1e-3) else None   # (noise-free test data: none)
    # each point's mean: the laser noise (the run's, else the point's own scatter) over sqrt(samples)
    per_sample = np.full(len(cut.static_u), noise) if noise is not None else np.array(cut.static_motion)
    std_error = np.where(per_sample > 0.0, per_sample, np.nan) / np.sqrt(np.maximum(cut.static_samples, 1))
    static = [StaticData(np.full(len(cut.static_u), mass), np.array(cut.static_u), np.array(cut.static_d),
                         source=f"{path} static segments", motion_rms_m=np.array(cut.static_motion),
                         std_error_m=std_error)
              ] if cut.static_u else []
    # one SineData per waveform: |U sin| (no offset) and offset + U sin (a planned second pass may add it);
    # a frequency recorded again in a waveform (at another amplitude, or by the second pass) goes into a
    # further SineData of that waveform, as a frequency appears once in each
    plain = _distinct_frequencies([s for s in cut.sines if s[2] == 0.0])
    offset = _distinct_frequencies([s for s in cut.sines if s[2] != 0.0])
    names = [f"{path} sine segments"] * bool(plain) + [f"{path} offset sine segments" if plain
                                                       else f"{path} sine segments"] * bool(offset)
    sines = [_sine_data(cut, g, noise, mass, name + (f" ({k + 1})" if k else ""), measured_inputs)
             for layers, name in zip([x for x in (plain, offset) if x], names) for k, g in enumerate(layers)]
    geometry = {k: getattr(base, k) for k in GEOMETRY_FIELDS}
    try:
        return ExperimentSet(
            membrane=str(info.get("membrane_name", base.name)), geometry=geometry, mass_kg=mass,
            static=static, steps=cut.steps, sines=sines, base_parameters=base, base_reference=str(membrane_ref),
            sensor_noise_m=noise,
            folder=Path(path),
        )
    except ExperimentError as exc:
        raise BagError(f"{path}: {exc}") from None
