"""Experiment protocols (no ROS): what the identifier node commands, as a time-indexed schedule.

A protocol YAML (``config/protocols/*.yaml``)::

    protocol:
      name: paper
      membrane: A2              # geometry and mass for the identification (preset or YAML)
      mass_kg: 0.003
      segments:
        - kind: static          # a voltage staircase: hold each level, measure the end
          voltages_V: [0, 2000, 2100, 2200, 2300, 2400, 2500]
          hold_s: 4.0
          measure_s: 1.0        # the last measure_s of each hold is averaged
        - kind: step            # the paper's step response (eq. 23)
          initial_V: 0
          final_V: 2200
          pre_s: 0.5
          hold_s: 4.0
        - kind: sine            # frequency response (eqs. 21, 24): each frequency held until steady
          amplitude_V: 2500
          offset_V: 0
          frequencies_Hz: [2, 5, 8, 9, 10, 12, 15, 20]
          settle_s: 5.0         # transient discarded
          measure_s: 3.0        # rounded up to whole periods
        - kind: rest            # back to 0 V
          hold_s: 1.0
      adaptive: false           # true: after the first fit, plan and run a second pass (below)
      adaptive_budget_s: 60     # experiment time of the second pass
      adaptive_max_settle_s: 60 # no hold of the second pass longer (the plan warns where it bites)

With ``adaptive: true`` the identifier plans the second pass from its first fit
(:func:`dea_ros.identify.planning.plan_experiments`) and runs the picks as the segments of
:func:`dea_ros.identify.planning.plan_protocol`, then identifies from both passes. Each planned record is
held until it has settled (:func:`dea_ros.identify.planning.record_settle`: from the slowest time constant
of the fitted membrane), at least as long as the first pass's record of its kind, at most
``adaptive_max_settle_s``.

:class:`Protocol.schedule` expands it into :class:`Segment` objects with absolute start/end
times (s from the protocol start), each with a ``voltage_at(t)`` function and the measurement
window, which the identifier records as metadata so experiments can be cut from the bag.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import yaml

from ..errors import ProtocolError
from ..model.parameters import config_dir
from ..model.yaml_files import read_yaml_mapping

__all__ = ["Protocol", "Segment", "ProtocolError", "load_protocol", "protocol_path", "segment_at", "commands_ahead"]


@dataclass(frozen=True)
class Segment:
    """One contiguous part of the experiment (s from the protocol start)."""

    index: int
    kind: str                   # static, step, sine, rest
    start_s: float
    end_s: float
    measure_start_s: float      # window used for identification
    measure_end_s: float
    info: dict                  # voltage, frequency, amplitude ... (SI units, JSON-able)
    voltage_at: Callable[[float], float] = field(repr=False, compare=False)

    def to_dict(self) -> dict:
        return {
            "index": self.index, "kind": self.kind, "start_s": self.start_s, "end_s": self.end_s,
            "measure_start_s": self.measure_start_s, "measure_end_s": self.measure_end_s, **self.info,
        }


def _num(seg: dict, key: str, where: str, default=None, positive=False, nonneg=False) -> float:
    if key not in seg:
        if default is None:
            raise ProtocolError(f"{where}: missing field '{key}'")
        return float(default)
    value = seg[key]
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ProtocolError(f"{where}: field '{key}' must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ProtocolError(f"{where}: field '{key}' must be finite")
    if positive and value <= 0:
        raise ProtocolError(f"{where}: field '{key}' must be > 0, got {value}")
    if nonneg and value < 0:
        raise ProtocolError(f"{where}: field '{key}' must be >= 0, got {value}")
    return value


def _list(seg: dict, key: str, where: str) -> list[float]:
    values = seg.get(key)
    if not isinstance(values, (list, tuple)) or not values:
        raise ProtocolError(f"{where}: field '{key}' must be a non-empty list of numbers")
    out = []
    for i, v in enumerate(values):
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise ProtocolError(f"{where}: '{key}[{i}]' must be a number, got {v!r}") from None
        if not math.isfinite(v):
            raise ProtocolError(f"{where}: '{key}[{i}]' must be finite")
        out.append(v)
    return out


_KNOWN = {
    "static": {"kind", "voltages_V", "hold_s", "measure_s"},
    "step": {"kind", "initial_V", "final_V", "pre_s", "hold_s"},
    "sine": {"kind", "amplitude_V", "offset_V", "frequencies_Hz", "settle_s", "measure_s"},
    "rest": {"kind", "hold_s"},
}


@dataclass(frozen=True)
class Protocol:
    name: str
    membrane: str
    mass_kg: float
    raw_segments: tuple
    source: str = ""
    adaptive: bool = False          # plan and run a second pass after the first fit
    adaptive_budget_s: float = 60.0  # its experiment time (s)
    adaptive_max_settle_s: float = 60.0  # no hold of it longer (s): PlanLimits.max_settle_s

    @classmethod
    def from_dict(cls, data: Any, source: str = "protocol") -> "Protocol":
        if isinstance(data, dict) and "protocol" in data:
            data = data["protocol"]
        if not isinstance(data, dict):
            raise ProtocolError(f"{source}: expected a mapping under 'protocol:'")
        segments = data.get("segments")
        if not isinstance(segments, list) or not segments:
            raise ProtocolError(f"{source}: 'segments' must be a non-empty list")
        mass = _num(data, "mass_kg", source, default=0.003, positive=True)
        if mass > 10:
            raise ProtocolError(f"{source}: mass_kg {mass} looks like grams; kg expected (3 g -> 0.003)")
        unknown = set(data) - {"name", "membrane", "mass_kg", "segments", "adaptive", "adaptive_budget_s",
                               "adaptive_max_settle_s"}
        if unknown:
            raise ProtocolError(f"{source}: unknown field(s) {sorted(unknown)}; allowed name, membrane, mass_kg, "
                                "segments, adaptive, adaptive_budget_s, adaptive_max_settle_s")
        adaptive = data.get("adaptive", False)
        if not isinstance(adaptive, bool):
            raise ProtocolError(f"{source}: 'adaptive' must be true or false, got {adaptive!r}")
        budget = _num(data, "adaptive_budget_s", source, default=60.0, positive=True)
        max_settle = _num(data, "adaptive_max_settle_s", source, default=60.0, positive=True)
        proto = cls(str(data.get("name", Path(source).stem)), str(data.get("membrane", "A2")), mass,
                    tuple(segments), source, adaptive, budget, max_settle)
        proto.schedule()  # validates every segment
        return proto

    def schedule(self, max_voltage_V: float | None = None) -> list[Segment]:
        """Expand into timed segments; ``max_voltage_V`` (if given) is checked for every level."""
        out: list[Segment] = []
        t = 0.0
        for k, seg in enumerate(self.raw_segments):
            where = f"{self.source}: segments[{k}]"
            if not isinstance(seg, dict) or "kind" not in seg:
                raise ProtocolError(f"{where}: needs a 'kind' (static, step, sine, rest)")
            kind = seg["kind"]
            if kind not in _KNOWN:
                raise ProtocolError(f"{where}: unknown kind {kind!r}; use static, step, sine or rest")
            unknown = set(seg) - _KNOWN[kind]
            if unknown:
                raise ProtocolError(f"{where}: unknown field(s) {sorted(unknown)} for kind {kind}; "
                                    f"allowed {sorted(_KNOWN[kind])}")
            peaks = []
            if kind == "static":
                hold = _num(seg, "hold_s", where, positive=True)
                meas = _num(seg, "measure_s", where, default=min(1.0, hold / 2), positive=True)
                if meas > hold:
                    raise ProtocolError(f"{where}: measure_s ({meas}) longer than hold_s ({hold})")
                for v in _list(seg, "voltages_V", where):
                    if v < 0:
                        raise ProtocolError(f"{where}: negative voltage {v}")
                    peaks.append(v)
                    out.append(Segment(len(out), "static", t, t + hold, t + hold - meas, t + hold,
                                       {"voltage_V": v}, _const(v)))
                    t += hold
            elif kind == "step":
                u0 = _num(seg, "initial_V", where, default=0.0, nonneg=True)
                u1 = _num(seg, "final_V", where, nonneg=True)
                pre = _num(seg, "pre_s", where, default=0.5, positive=True)
                hold = _num(seg, "hold_s", where, positive=True)
                peaks += [u0, u1]
                t_step = t + pre
                out.append(Segment(len(out), "step", t, t + pre + hold, t, t + pre + hold,
                                   {"initial_V": u0, "final_V": u1, "step_time_s": t_step},
                                   _step(u0, u1, t_step)))
                t += pre + hold
            elif kind == "sine":
                amp = _num(seg, "amplitude_V", where, positive=True)
                off = _num(seg, "offset_V", where, default=0.0, nonneg=True)
                settle = _num(seg, "settle_s", where, positive=True)
                meas = _num(seg, "measure_s", where, positive=True)
                if off - amp < -1e-9 and off != 0.0:
                    raise ProtocolError(f"{where}: offset_V - amplitude_V < 0 (negative voltage)")
                for f in _list(seg, "frequencies_Hz", where):
                    if f <= 0:
                        raise ProtocolError(f"{where}: frequency {f} Hz must be > 0")
                    periods = max(1, math.ceil(meas * f - 1e-9))
                    settle_p = math.ceil(settle * f - 1e-9) / f  # whole periods: the phase restarts at 0
                    dur = settle_p + periods / f
                    peaks.append(off + amp)
                    out.append(Segment(len(out), "sine", t, t + dur, t + settle_p, t + dur,
                                       {"frequency_Hz": f, "amplitude_V": amp, "offset_V": off,
                                        "periods": periods}, _sine(amp, off, f, t)))
                    t += dur
            else:  # rest
                hold = _num(seg, "hold_s", where, positive=True)
                out.append(Segment(len(out), "rest", t, t + hold, t, t + hold, {"voltage_V": 0.0}, _const(0.0)))
                t += hold
            if max_voltage_V is not None and peaks and max(peaks) > max_voltage_V:
                raise ProtocolError(f"{where}: {max(peaks):.0f} V exceeds the rig's maximum {max_voltage_V:.0f} V")
        return out

    def to_dict(self) -> dict:
        """The protocol as its YAML mapping (``{"protocol": {...}}``)."""
        return {"protocol": {"name": self.name, "membrane": self.membrane, "mass_kg": self.mass_kg,
                             "adaptive": self.adaptive, "adaptive_budget_s": self.adaptive_budget_s,
                             "adaptive_max_settle_s": self.adaptive_max_settle_s,
                             "segments": [dict(s) for s in self.raw_segments]}}

    def write_yaml(self, path) -> Path:
        """Write the protocol as YAML (loadable by :func:`load_protocol`)."""
        path = Path(path)
        path.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))
        return path

    def duration_s(self) -> float:
        segs = self.schedule()
        return segs[-1].end_s if segs else 0.0


def segment_at(segments, t: float, start: int = 0) -> int:
    """The index of the segment that holds protocol time ``t`` (s), searching from ``start``;
    ``len(segments)`` past the end."""
    k = start
    while k < len(segments) and t >= segments[k].end_s:
        k += 1
    return k


def commands_ahead(segments, k: int, t: float, period_s: float, n: int) -> list:
    """The commands (V) of the ticks at t, t + period, ... (n of them), each for the update one period
    later (identifier_node's command timing): from segment ``k`` on, 0 V past the end."""
    out = []
    for i in range(n):
        tick_t = t + i * period_s
        k = segment_at(segments, tick_t, k)
        out.append(float(segments[k].voltage_at(tick_t + period_s)) if k < len(segments) else 0.0)
    return out


def _const(v):
    return lambda t: v


def _step(u0, u1, t_step):
    return lambda t: u0 if t < t_step else u1


def _sine(amp, off, f, t0):
    """The sine command from its segment start t0.

    Without offset the paper's u = U sin(wt) is applied as |U sin(wt)|: the amplifier output
    is unipolar (negative commands are refused by the safety controller) and the model sees
    only u^2 (eq. 6), so the excitation is the same. It needs a slew limit >= U w.
    """
    w = 2.0 * math.pi * f
    if off == 0.0:
        return lambda t: abs(amp * math.sin(w * (t - t0)))
    return lambda t: off + amp * math.sin(w * (t - t0))


def protocol_path(name: str) -> Path:
    """The YAML file of a shipped protocol (``config/protocols/<name>.yaml``)."""
    return config_dir() / "protocols" / f"{name}.yaml"


def load_protocol(name_or_path: str | Path) -> Protocol:
    """A protocol name in config/protocols (e.g. ``paper``, ``quick``) or a YAML path."""
    p = Path(name_or_path)
    if not p.is_file():
        candidate = protocol_path(str(name_or_path))
        if not candidate.is_file():
            raise ProtocolError(f"no protocol file {name_or_path!r} (nor {candidate})")
        p = candidate
    data = read_yaml_mapping(p, ProtocolError, "protocol file", fix="give a protocol name or a YAML path",
                             mapping="a mapping 'protocol: {segments: [...]}'")
    return Protocol.from_dict(data, source=str(p))
