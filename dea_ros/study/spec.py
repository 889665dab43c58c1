"""The study specification (a YAML file, ``docs/study.md``) and the designs it describes.

A spec names a base membrane, the parameters that vary (membrane fields of
:class:`~dea_ros.model.parameters.MembraneParameters` and the excitation), how they are sampled
(a full grid, or a seeded Latin hypercube or Sobol sample from :mod:`scipy.stats.qmc`) and
what is computed per design (static stroke over a voltage range, a frequency sweep). Every
error is a :class:`SpecError` naming the field and the fix.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from scipy.stats import qmc

from ..errors import SpecError
from ..model.yaml_files import read_yaml_mapping
from ..solvers.inputs import check_harmonics

__all__ = ["SpecError", "StudySpec", "Variable", "load_spec", "parse_spec", "spec_from_dict", "MEMBRANE_FIELDS",
           "EXCITATION_FIELDS", "SAMPLING_METHODS"]

#: Membrane fields a study can vary (SI units as in the field names).
MEMBRANE_FIELDS = ("prestretch", "thickness_m", "plate_radius_m", "electrode_width_m", "mass_kg",
                   "relative_permittivity", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "breakdown_field_V_per_m")
#: Excitation fields a study can vary (sine u = offset + amplitude sin(2 pi f t), sweep range).
EXCITATION_FIELDS = ("amplitude_V", "offset_V", "f_min_Hz", "f_max_Hz")
SAMPLING_METHODS = ("grid", "lhs", "sobol")
_TOP_KEYS = ("name", "base", "parameters", "sampling", "excitation", "static", "sweep", "output", "plots",
             "prestretch_rule", "breakdown_margin")
_EXCITATION_DEFAULTS = {"amplitude_V": 2500.0, "offset_V": 0.0, "f_min_Hz": 0.1, "f_max_Hz": 20.0}
_SWEEP_DEFAULTS = {"points": 200, "spacing": "lin", "harmonics": 8, "stability": True, "branch_switching": True,
                   "realised": False}
#: Largest number of designs one spec may describe (a grid multiplies quickly).
MAX_DESIGNS = 10_000_000


@dataclass(frozen=True)
class Variable:
    """One varied parameter: a range (sampled) or explicit values (grid)."""

    name: str
    low: float
    high: float
    values: tuple = ()          # explicit values (grid); empty for a range
    points: int = 0             # grid points over [low, high] when no values
    scale: str = "lin"          # "lin" or "log"

    def grid_values(self) -> np.ndarray:
        if self.values:
            return np.asarray(self.values, float)
        if self.scale == "log":
            return np.geomspace(self.low, self.high, self.points)
        return np.linspace(self.low, self.high, self.points)

    def from_unit(self, q: np.ndarray) -> np.ndarray:
        """Map samples in [0, 1) to the range (log-uniform for ``scale: log``; nearest value for a list)."""
        if self.values:
            vals = np.asarray(self.values, float)
            return vals[np.minimum((q * vals.size).astype(int), vals.size - 1)]
        if self.scale == "log":
            return np.exp(math.log(self.low) + q * (math.log(self.high) - math.log(self.low)))
        return self.low + q * (self.high - self.low)


@dataclass
class StudySpec:
    """A validated study spec (see the module docstring and ``docs/study.md``)."""

    name: str
    base: str
    variables: list
    method: str
    n: int
    seed: int
    excitation: dict
    static_voltages: int
    static_max_V: float | None
    sweep: dict
    chunk_size: int
    output_format: str
    plots: list
    prestretch_rule: str = "ogden"
    breakdown_margin: float = 0.9
    source: str = "spec"
    raw: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ designs
    @property
    def names(self) -> list:
        return [v.name for v in self.variables]

    def designs(self) -> np.ndarray:
        """(n_designs, n_variables) values of the varied parameters, in a fixed order."""
        if not self.variables:
            return np.zeros((1, 0))
        if self.method == "grid":
            axes = [v.grid_values() for v in self.variables]
            mesh = np.meshgrid(*axes, indexing="ij")
            return np.stack([m.reshape(-1) for m in mesh], axis=1)
        d = len(self.variables)
        if self.method == "lhs":
            sampler = qmc.LatinHypercube(d=d, seed=self.seed)
            q = sampler.random(self.n)
        else:
            sampler = qmc.Sobol(d=d, scramble=True, seed=self.seed)
            q = sampler.random(self.n)
        return np.stack([v.from_unit(q[:, k]) for k, v in enumerate(self.variables)], axis=1)

    @property
    def n_designs(self) -> int:
        if self.method == "grid":
            return int(np.prod([len(v.values) or v.points for v in self.variables])) if self.variables else 1
        return self.n

    def fingerprint(self) -> str:
        """A hash of everything that changes the results (resuming needs the same one)."""
        data = {k: v for k, v in self.raw.items() if k != "plots"}
        text = json.dumps(data, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        return dict(self.raw)


def _number(where: str, value, positive: bool = False) -> float:
    if isinstance(value, str):   # PyYAML reads 3e-5 (no dot) as text: accept a number written so
        try:
            value = float(value)
        except ValueError:
            raise SpecError(f"{where}: a number is needed (SI units), got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(f"{where}: a number is needed (SI units), got {value!r}")
    x = float(value)
    if not math.isfinite(x) or (positive and x <= 0):
        raise SpecError(f"{where}: must be a {'positive ' if positive else ''}finite number, got {value!r}")
    return x


def _integer(where: str, value, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise SpecError(f"{where}: an integer from {low} to {high} is needed, got {value!r}")
    return int(value)


def _mapping(where: str, value) -> dict:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise SpecError(f"{where}: a mapping of key: value is needed, got {type(value).__name__}")
    return dict(value)


def _unknown(where: str, data: Mapping, allowed) -> None:
    bad = sorted(str(k) for k in data if k not in allowed)
    if bad:
        raise SpecError(f"{where}: unknown key(s) {bad}; allowed: {sorted(allowed)}")


def _variable(name: str, entry, method: str) -> Variable:
    where = f"parameters.{name}"
    if name not in MEMBRANE_FIELDS + EXCITATION_FIELDS:
        raise SpecError(f"parameters: {name!r} cannot be varied; choose membrane fields {list(MEMBRANE_FIELDS)} "
                        f"or excitation fields {list(EXCITATION_FIELDS)}")
    if isinstance(entry, (list, tuple)):
        entry = {"values": list(entry)}
    entry = _mapping(where, entry)
    _unknown(where, entry, ("min", "max", "values", "points", "scale"))
    scale = entry.get("scale", "lin")
    if scale not in ("lin", "log"):
        raise SpecError(f"{where}.scale: 'lin' or 'log', got {scale!r}")
    if "values" in entry:
        if "min" in entry or "max" in entry:
            raise SpecError(f"{where}: give either values: [...] or min/max, not both")
        vals = entry["values"]
        if not isinstance(vals, (list, tuple)) or not vals:
            raise SpecError(f"{where}.values: a non-empty list of numbers is needed")
        vals = tuple(_number(f"{where}.values", v) for v in vals)
        return Variable(name, min(vals), max(vals), values=vals, scale=scale)
    if "min" not in entry or "max" not in entry:
        raise SpecError(f"{where}: needs min and max (a range) or values: [...]")
    lo, hi = _number(f"{where}.min", entry["min"]), _number(f"{where}.max", entry["max"])
    if hi <= lo:
        raise SpecError(f"{where}: max ({hi:g}) must be larger than min ({lo:g})")
    if scale == "log" and lo <= 0:
        raise SpecError(f"{where}: scale log needs min > 0, got {lo:g}")
    points = 0
    if method == "grid":
        if "points" not in entry:
            raise SpecError(f"{where}: sampling method grid needs points: N (or values: [...])")
        points = _integer(f"{where}.points", entry["points"], 2, 100000)
    elif "points" in entry:
        raise SpecError(f"{where}.points: only for sampling method grid (lhs/sobol take sampling.n)")
    return Variable(name, lo, hi, points=points, scale=scale)


def _parse_sampling(data: Mapping) -> tuple[str, int, int]:
    """``sampling``: (method, number of designs for lhs/sobol (0 for a grid), seed)."""
    sampling = _mapping("sampling", data.get("sampling"))
    _unknown("sampling", sampling, ("method", "n", "seed"))
    method = sampling.get("method", "grid")
    if method not in SAMPLING_METHODS:
        raise SpecError(f"sampling.method: one of {list(SAMPLING_METHODS)}, got {method!r}")
    seed = _integer("sampling.seed", sampling.get("seed", 0), 0, 2**32 - 1)
    n = 0
    if method != "grid":
        if "n" not in sampling:
            raise SpecError(f"sampling.n: the number of designs is needed for method {method}")
        n = _integer("sampling.n", sampling["n"], 1, MAX_DESIGNS)
        if method == "sobol" and n & (n - 1):
            raise SpecError(f"sampling.n: a Sobol sample needs a power of 2 (balance), got {n}; "
                            f"use {1 << (n - 1).bit_length()} or method lhs")
    elif "n" in sampling:
        raise SpecError("sampling.n: only for lhs/sobol; a grid has points per parameter")
    return method, n, seed


def _parse_excitation(data: Mapping, variables: list) -> dict:
    """``excitation``: the fixed excitation fields (defaults filled in), none also varied."""
    exc = _mapping("excitation", data.get("excitation"))
    _unknown("excitation", exc, EXCITATION_FIELDS)
    excitation = dict(_EXCITATION_DEFAULTS)
    for k, v in exc.items():
        excitation[k] = _number(f"excitation.{k}", v, positive=k in ("f_min_Hz", "f_max_Hz"))
    for v in variables:
        if v.name in exc:
            raise SpecError(f"excitation.{v.name}: also given under parameters; give it in one place")
        if v.name in ("f_min_Hz", "f_max_Hz") and v.low <= 0:
            raise SpecError(f"parameters.{v.name}: frequencies must be > 0")
    return excitation


def _parse_static(data: Mapping) -> tuple[int, float | None]:
    """``static``: (number of voltages of the static stroke, their maximum in V or None)."""
    static = _mapping("static", data.get("static"))
    _unknown("static", static, ("voltages", "max_V"))
    n_static = _integer("static.voltages", static.get("voltages", 11), 2, 10000)
    static_max = _number("static.max_V", static["max_V"], positive=True) if "max_V" in static else None
    return n_static, static_max


def _parse_sweep(data: Mapping) -> dict:
    """``sweep``: the frequency sweep's settings (defaults filled in)."""
    sweep = _mapping("sweep", data.get("sweep"))
    _unknown("sweep", sweep, tuple(_SWEEP_DEFAULTS))
    sw = dict(_SWEEP_DEFAULTS)
    sw.update(sweep)
    sw["points"] = _integer("sweep.points", sw["points"], 2, 5000)
    try:
        sw["harmonics"] = check_harmonics(sw["harmonics"], "sweep.harmonics")
    except ValueError as exc_:
        raise SpecError(str(exc_)) from None
    if sw["spacing"] not in ("lin", "log"):
        raise SpecError(f"sweep.spacing: 'lin' or 'log', got {sw['spacing']!r}")
    for key in ("stability", "branch_switching", "realised"):
        if not isinstance(sw[key], bool):
            raise SpecError(f"sweep.{key}: true or false, got {sw[key]!r}")
    return sw


def _parse_output(data: Mapping) -> tuple[int, str]:
    """``output``: (designs per chunk, results format)."""
    output = _mapping("output", data.get("output"))
    _unknown("output", output, ("chunk_size", "format"))
    chunk = _integer("output.chunk_size", output.get("chunk_size", 25), 1, 100000)
    fmt = output.get("format", "auto")
    if fmt not in ("auto", "parquet", "csv"):
        raise SpecError(f"output.format: auto, parquet or csv, got {fmt!r}")
    return chunk, fmt


def _parse_plots(data: Mapping, names: list) -> list:
    """``plots``: [x, y] pairs of varied parameters (default: the first two)."""
    plots = data.get("plots")
    if plots is None:
        plots = [names[:2]] if len(names) >= 2 else []
    if not isinstance(plots, list):
        raise SpecError("plots: a list of [x, y] parameter pairs is needed, e.g. [[prestretch, thickness_m]]")
    pairs = []
    for k, pair in enumerate(plots):
        if isinstance(pair, Mapping):
            pair = [pair.get("x"), pair.get("y")]
        if not isinstance(pair, (list, tuple)) or len(pair) != 2 or any(p not in names for p in pair):
            raise SpecError(f"plots[{k}]: a pair [x, y] of varied parameters {names} is needed, got {pair!r}")
        pairs.append([str(pair[0]), str(pair[1])])
    return pairs


def _parse_design_rules(data: Mapping) -> tuple[str, float]:
    """(``prestretch_rule``, ``breakdown_margin``)."""
    rule = data.get("prestretch_rule", "ogden")
    if rule not in ("ogden", "fixed"):
        raise SpecError(f"prestretch_rule: 'ogden' (beta, gamma follow eqs. 8-9) or 'fixed', got {rule!r}")
    margin = _number("breakdown_margin", data.get("breakdown_margin", 0.9), positive=True)
    if margin >= 1.0:
        raise SpecError(f"breakdown_margin: must be in (0, 1), got {margin:g}")
    return rule, margin


def parse_spec(data, source: str = "spec") -> StudySpec:
    """Validate a spec mapping (as read from YAML); raise :class:`SpecError` naming the field."""
    data = _mapping(source, data)
    _unknown(source, data, _TOP_KEYS)
    name = str(data.get("name") or Path(source).stem or "study")
    base = data.get("base", "A2")
    if not isinstance(base, str) or not base.strip():
        raise SpecError("base: a preset name (LP1, A1, A2) or a parameters YAML path is needed")
    method, n, seed = _parse_sampling(data)
    params = _mapping("parameters", data.get("parameters"))
    variables = [_variable(str(k), v, method) for k, v in params.items()]
    excitation = _parse_excitation(data, variables)
    n_static, static_max = _parse_static(data)
    sweep = _parse_sweep(data)
    chunk, fmt = _parse_output(data)
    plots = _parse_plots(data, [v.name for v in variables])
    rule, margin = _parse_design_rules(data)
    spec = StudySpec(name=name, base=base.strip(), variables=variables, method=method, n=n, seed=seed,
                     excitation=excitation, static_voltages=n_static, static_max_V=static_max, sweep=sweep,
                     chunk_size=chunk, output_format=fmt, plots=plots, prestretch_rule=rule,
                     breakdown_margin=margin, source=source, raw=json.loads(json.dumps(data, default=str)))
    if spec.n_designs > MAX_DESIGNS:
        raise SpecError(f"parameters: the grid has {spec.n_designs} designs, more than {MAX_DESIGNS}; "
                        "use fewer points or sampling method lhs/sobol")
    if not variables:
        raise SpecError("parameters: name at least one parameter to vary, e.g. thickness_m: {min: 2.5e-5, max: 5e-5}")
    return spec


def load_spec(path) -> StudySpec:
    """Read and validate a spec YAML file."""
    data = read_yaml_mapping(path, SpecError, "spec file",
                             fix="give a study spec YAML such as config/studies/a2_family.yaml (docs/study.md)",
                             mapping="a mapping (name, base, parameters, sampling, ...)")
    return parse_spec(data, source=str(path))


def spec_from_dict(data: dict[str, Any], source: str = "spec") -> StudySpec:
    """Alias of :func:`parse_spec` for library use (a spec built in Python)."""
    return parse_spec(data, source)
