"""Membrane parameters: a typed, validated object with YAML I/O (SI units).

The fields follow Tables I and II of the paper. Every quantity is stored in SI
units and the unit is part of the field name where it is not dimensionless:

========================  ==========================  ======================
field                     paper symbol                unit
========================  ==========================  ======================
prestretch                lambda_p (Table I)          -
thickness_m               z0 (Table I)                m
plate_radius_m            r (Table I)                 m
electrode_width_m         l0 (Table I)                m
mass_kg                   m (eq. 5)                   kg
relative_permittivity     eps_r (eq. 6)               -
k1_Pa                     k1 (eq. 11)                 Pa
eta1_Pa_s                 eta1 (eq. 11)               Pa s
eta2_Pa_s                 eta2 (eq. 12)               Pa s
beta_Pa                   beta_1..3 (eqs. 8, 10)      Pa
gamma_Pa                  gamma_1..3 (eqs. 9, 10)     Pa
breakdown_field_V_per_m   dielectric breakdown        V/m
gravity_m_per_s2          g (eq. 5)                   m/s^2
vacuum_permittivity_F_per_m  eps0 (eq. 6)             F/m
========================  ==========================  ======================

Two levels of checks:

* construction (:class:`MembraneParameters` itself, also ``replace()`` inside the fits):
  types, finite values, signs and broad SI-unit ranges;
* plausibility (:meth:`MembraneParameters.plausibility_problems`, enforced for every
  file and mapping read by :meth:`MembraneParameters.from_dict` / ``from_yaml`` /
  :func:`load_parameters`): the ranges a real DEA membrane lies in
  (:data:`PLAUSIBLE_RANGES`), so that unit slips (micrometres typed as metres,
  MPa for Pa, a percentage for a stretch, a typo in an exponent) are refused with
  a message naming the field and the likely slip; a file named like a paper preset
  (LP1, A1, A2) must also have that preset's geometry (Table I) within a factor 3.
"""
from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from ..errors import ParameterError
from .yaml_files import read_yaml_mapping

try:  # optional: the ament index of a sourced ROS 2 workspace (absent outside ROS)
    from ament_index_python.packages import get_package_share_directory
except ImportError:
    get_package_share_directory = None

__all__ = [
    "MembraneParameters",
    "ParameterError",
    "PRESET_NAMES",
    "PLAUSIBLE_RANGES",
    "MAX_BREAKDOWN_FIELD_V_PER_M",
    "preset",
    "preset_path",
    "config_dir",
    "load_parameters",
]

PRESET_NAMES = ("LP1", "A1", "A2")

#: Highest plausible dielectric breakdown field, V/m (300 V/um). This project's limit is
#: ``margin x breakdown field x z0`` with z0 the (prestretched) membrane thickness, so the field
#: meant is the *nominal* one, V/z0 at breakdown. Silicones (Elastosil, the paper's 80-100 V/um)
#: reach 80-150 V/um; acrylic VHB reaches up to ~220 V/um nominal at large equibiaxial
#: prestretch (Kofod et al. 2003; Huang et al. 2012, APL 101:122905). The higher values quoted
#: for VHB (412 V/um, Pelrine et al. 2000) are true fields across the film thinned by the
#: voltage, not V/z0. Anything above 300 V/um is taken for a typo (8e8 for 8e7).
MAX_BREAKDOWN_FIELD_V_PER_M = 3.0e8

#: Plausible range of each field, (low, high, unit, hint for a value below, hint for a value above).
#: A value outside is refused by :meth:`MembraneParameters.from_dict` as a likely unit slip.
PLAUSIBLE_RANGES = {
    "prestretch": (1.0, 10.0, "", "lambda_p is a stretch ratio >= 1, not a strain (19 % prestretch -> 1.19)",
                   "lambda_p is a stretch ratio, not a percentage (19 % prestretch -> 1.19)"),
    "thickness_m": (1e-6, 1e-3, "m", "DEA membranes are 1-1000 um thick (35 um -> 3.5e-05 m)",
                    "DEA membranes are 1-1000 um thick; micrometres or millimetres typed as metres? "
                    "(35 um -> 3.5e-05 m)"),
    "plate_radius_m": (1e-4, 0.1, "m", "millimetres are 1e-3 m (4.5 mm -> 0.0045)",
                       "millimetres typed as metres? (4.5 mm -> 0.0045)"),
    "electrode_width_m": (1e-3, 0.5, "m", "millimetres are 1e-3 m (17 mm -> 0.017)",
                          "millimetres typed as metres? (17 mm -> 0.017)"),
    "mass_kg": (0.0, 1.0, "kg", "", "grams typed as kilograms? (3 g -> 0.003)"),
    "relative_permittivity": (1.0, 100.0, "", "eps_r is dimensionless and >= 1 (about 2-10 for elastomers)",
                              "eps_r is dimensionless, about 2-10 for elastomers (F/m given? eps_r = eps / eps0)"),
    "k1_Pa": (1e3, 1e11, "Pa", "given in MPa or kPa? (40.25 MPa -> 4.025e7 Pa)", "given in mPa or kPa x 1e6?"),
    "eta1_Pa_s": (1e1, 1e13, "Pa s", "given in MPa s? (37.58 MPa s -> 3.758e7 Pa s)", "a typo in the exponent?"),
    "eta2_Pa_s": (1e-1, 1e9, "Pa s", "given in kPa s or MPa s? (35.11 kPa s -> 35110 Pa s); 0 is allowed",
                  "a typo in the exponent?"),
    "breakdown_field_V_per_m": (1e6, MAX_BREAKDOWN_FIELD_V_PER_M, "V/m",
                                "given in V/um or kV/mm? (100 V/um -> 1e8 V/m)",
                                "no elastomer reaches this nominal field (silicone 80-150 V/um, "
                                "prestretched VHB up to ~220 V/um); a typo in the exponent? (80 V/um -> 8e7)"),
    "gravity_m_per_s2": (0.0, 20.0, "m/s^2", "", "cm/s^2 given? (9.81 m/s^2)"),
    "vacuum_permittivity_F_per_m": (8.8e-12, 8.9e-12, "F/m", "eps0 = 8.854e-12 F/m", "eps0 = 8.854e-12 F/m"),
}
#: Ogden coefficients (beta_Pa, gamma_Pa): at most this large in magnitude, Pa.
_OGDEN_MAX_PA = 1e9
#: ... and when any is non-zero, the largest at least this large (else: given in MPa?), Pa.
_OGDEN_MIN_PA = 10.0
#: Geometry of the paper's membranes (Table I): a file named like a preset must match it.
_PRESET_GEOMETRY = {
    "LP1": {"prestretch": 1.15, "thickness_m": 38e-6, "plate_radius_m": 4.5e-3, "electrode_width_m": 14e-3},
    "A1": {"prestretch": 1.36, "thickness_m": 27e-6, "plate_radius_m": 4.5e-3, "electrode_width_m": 17e-3},
    "A2": {"prestretch": 1.19, "thickness_m": 35e-6, "plate_radius_m": 4.5e-3, "electrode_width_m": 17e-3},
}
#: A preset-named file whose geometry differs by more than this factor is taken for a slip.
_PRESET_GEOMETRY_FACTOR = 3.0


@dataclass(frozen=True)
class MembraneParameters:
    """Parameters of the mass-loaded circular DEA model (paper eqs. 1-12).

    Instances are immutable; use :meth:`replace` to derive a modified copy.
    Construction validates every field and raises :class:`ParameterError`
    naming the offending field.
    """

    name: str
    prestretch: float
    thickness_m: float
    plate_radius_m: float
    electrode_width_m: float
    mass_kg: float
    relative_permittivity: float
    k1_Pa: float
    eta1_Pa_s: float
    eta2_Pa_s: float
    beta_Pa: tuple[float, float, float]
    gamma_Pa: tuple[float, float, float]
    breakdown_field_V_per_m: float = 100e6
    gravity_m_per_s2: float = 9.81
    vacuum_permittivity_F_per_m: float = 8.85e-12
    notes: str = field(default="", compare=False)

    # ------------------------------------------------------------------ checks
    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ParameterError("field 'name': must be a non-empty string")
        for key in ("beta_Pa", "gamma_Pa"):
            value = getattr(self, key)
            try:
                values = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                raise ParameterError(
                    f"field '{key}': must be a list of three numbers in Pa, got {value!r}"
                ) from None
            if len(values) != 3:
                raise ParameterError(
                    f"field '{key}': must have exactly 3 Ogden coefficients (i = 1, 2, 3), "
                    f"got {len(values)}"
                )
            for i, v in enumerate(values):
                if not math.isfinite(v):
                    raise ParameterError(f"field '{key}[{i}]': must be finite, got {v}")
            object.__setattr__(self, key, values)
        for f in dataclasses.fields(self):
            if f.name in ("name", "notes", "beta_Pa", "gamma_Pa"):
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool):
                raise ParameterError(f"field '{f.name}': must be a number, got {value!r}")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ParameterError(
                    f"field '{f.name}': must be a number, got {value!r}"
                ) from None
            if not math.isfinite(value):
                raise ParameterError(f"field '{f.name}': must be finite, got {value}")
            object.__setattr__(self, f.name, value)
        positive = (
            "prestretch", "thickness_m", "plate_radius_m", "electrode_width_m",
            "relative_permittivity", "k1_Pa", "eta1_Pa_s", "breakdown_field_V_per_m",
            "vacuum_permittivity_F_per_m",
        )
        for key in positive:
            if getattr(self, key) <= 0.0:
                raise ParameterError(f"field '{key}': must be > 0, got {getattr(self, key)}")
        if self.mass_kg < 0.0:
            raise ParameterError(f"field 'mass_kg': must be >= 0, got {self.mass_kg}")
        if self.eta2_Pa_s < 0.0:
            raise ParameterError(f"field 'eta2_Pa_s': must be >= 0, got {self.eta2_Pa_s}")
        if self.gravity_m_per_s2 < 0.0:
            raise ParameterError(
                f"field 'gravity_m_per_s2': must be >= 0, got {self.gravity_m_per_s2}"
            )
        # Unit slips: SI values far outside the physical range of a DEA.
        unit_checks = (
            ("thickness_m", 1e-7, 1e-2, "micrometres are 1e-6 m: 35 um -> 3.5e-05"),
            ("electrode_width_m", 1e-4, 1.0, "millimetres are 1e-3 m: 17 mm -> 0.017"),
            ("plate_radius_m", 1e-5, 1.0, "millimetres are 1e-3 m: 4.5 mm -> 0.0045"),
            ("mass_kg", 0.0, 10.0, "grams are 1e-3 kg: 3 g -> 0.003"),
            ("relative_permittivity", 1.0, 1e4, "eps_r is dimensionless, about 2-10"),
        )
        for key, low, high, hint in unit_checks:
            value = getattr(self, key)
            if not (low <= value <= high):
                raise ParameterError(
                    f"field '{key}': {value} is outside [{low}, {high}]; SI units expected ({hint})"
                )

    # ------------------------------------------------------------- plausibility
    def plausibility_problems(self) -> list[str]:
        """Every field outside the range a real DEA membrane lies in, as messages naming the
        field, the plausible range and the likely slip (empty when plausible)."""
        problems: list[str] = []
        for key, (low, high, unit, hint_low, hint_high) in PLAUSIBLE_RANGES.items():
            value = getattr(self, key)
            if key == "eta2_Pa_s" and value == 0.0:
                continue
            if low <= value <= high:
                continue
            hint = hint_low if value < low else hint_high
            unit_text = f" {unit}" if unit else ""
            problems.append(
                f"field '{key}': {value:g}{unit_text} is outside the plausible range "
                f"[{low:g}, {high:g}]{unit_text}" + (f"; {hint}" if hint else "")
            )
        for key in ("beta_Pa", "gamma_Pa"):
            values = getattr(self, key)
            largest = max(abs(v) for v in values)
            if largest > _OGDEN_MAX_PA:
                problems.append(
                    f"field '{key}': |{key}| up to {largest:g} Pa is above {_OGDEN_MAX_PA:g} Pa; "
                    "a typo in the exponent?"
                )
            elif 0.0 < largest < _OGDEN_MIN_PA:
                problems.append(
                    f"field '{key}': the largest coefficient is {largest:g} Pa, below {_OGDEN_MIN_PA:g} Pa; "
                    "given in MPa or kPa? (0.343 MPa -> 343000 Pa)"
                )
        reference = _PRESET_GEOMETRY.get(self.name.strip().upper())
        if reference is not None:
            for key, expected in reference.items():
                value = getattr(self, key)
                ratio = value / expected
                if not (1.0 / _PRESET_GEOMETRY_FACTOR <= ratio <= _PRESET_GEOMETRY_FACTOR):
                    problems.append(
                        f"field '{key}': {value:g} is {ratio:.3g} x the value {expected:g} of the paper's "
                        f"membrane {self.name.strip().upper()} (Table I) this file is named after; a unit or "
                        "exponent slip? (give a different membrane another name)"
                    )
        return problems

    def check_plausible(self, source: str = "parameters") -> "MembraneParameters":
        """Raise :class:`ParameterError` listing every implausible field; return self otherwise."""
        problems = self.plausibility_problems()
        if problems:
            raise ParameterError(f"{source}: " + "; ".join(problems))
        return self

    # ------------------------------------------------------------- derived
    @property
    def c1bar_m(self) -> float:
        """c1bar = 2 pi r z0 / l0 in m (paper, after eq. 18): 2 pi r z sin(theta) = c1bar d/s(d)."""
        return 2.0 * math.pi * self.plate_radius_m * self.thickness_m / self.electrode_width_m

    @property
    def c2_Pa_per_V2(self) -> float:
        """c2 = -eps0 eps_r / z0^2 in Pa/V^2 (eq. 6); sigma_Maxwell = c2 s(d) u^2."""
        return -self.vacuum_permittivity_F_per_m * self.relative_permittivity / self.thickness_m**2

    @property
    def relaxation_time_s(self) -> float:
        """Time constant eta1/k1 of the viscoelastic branch (eq. 11), s."""
        return self.eta1_Pa_s / self.k1_Pa

    @property
    def prestress_Pa(self) -> float:
        """Hyperelastic stress of the flat membrane, sigma_h(lambda_r = 1) = sum(beta - gamma) (eq. 10)."""
        return sum(self.beta_Pa) - sum(self.gamma_Pa)

    def breakdown_voltage_V(self) -> float:
        """Voltage at the breakdown field across the undeformed thickness z0, V."""
        return self.breakdown_field_V_per_m * self.thickness_m

    def max_safe_voltage_V(self, margin: float = 0.9) -> float:
        """Breakdown voltage times a safety margin in (0, 1) (strictly below 1), V."""
        if not (0.0 < margin < 1.0):
            raise ParameterError(
                f"margin must be in (0, 1), strictly below 1 (no headroom at 1: the membrane thins "
                f"under voltage and the breakdown field scatters); got {margin}")
        return margin * self.breakdown_voltage_V()

    @staticmethod
    def ogden_beta_gamma_from_mu(mu_Pa, prestretch: float):
        """beta_i = mu_i lambda_p^(2i), gamma_i = mu_i lambda_p^(-4i) (eqs. 8-9)."""
        mu = [float(m) for m in mu_Pa]
        beta = tuple(m * prestretch ** (2 * (i + 1)) for i, m in enumerate(mu))
        gamma = tuple(m * prestretch ** (-4 * (i + 1)) for i, m in enumerate(mu))
        return beta, gamma

    def replace(self, **changes: Any) -> "MembraneParameters":
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (lists for the Ogden coefficients), as written to YAML."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "notes" and not value:
                continue
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "parameters",
                  require: tuple[str, ...] = ()) -> "MembraneParameters":
        """Build from a mapping; unknown or missing keys raise :class:`ParameterError`.

        The result must be plausible (:meth:`plausibility_problems`). ``require`` names
        fields that have a default but must be given explicitly (e.g. the amplifier needs
        ``breakdown_field_V_per_m`` stated, never defaulted).
        """
        if not isinstance(data, Mapping):
            raise ParameterError(
                f"{source}: expected a mapping of field: value, got {type(data).__name__}"
            )
        known = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ParameterError(
                f"{source}: unknown field(s) {unknown}; allowed fields are {sorted(known)}"
            )
        required = [
            f.name for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        ]
        missing = [k for k in required if k not in data]
        if missing:
            raise ParameterError(
                f"{source}: missing field(s) {missing}; every membrane file needs {required}"
            )
        missing = [k for k in require if k not in data]
        if missing:
            hint = (" (the amplifier derives its voltage limit from it: state the film's breakdown "
                    "field, e.g. 1.0e8 for 100 V/um; it is never defaulted)"
                    if "breakdown_field_V_per_m" in missing else "")
            raise ParameterError(f"{source}: missing field(s) {missing}, required here{hint}")
        try:
            params = cls(**dict(data))
        except ParameterError as exc:
            raise ParameterError(f"{source}: {exc}") from None
        return params.check_plausible(source)

    def to_yaml(self, path: str | Path | None = None, header: str | None = None) -> str:
        """Write YAML (SI units, documented in a header comment); return the text."""
        lines = [
            "# dea_ros membrane parameters, SI units (m, kg, Pa, Pa s, V/m).",
            "# Fields: see dea_ros.model.parameters; paper eqs. 1-12, Tables I-II.",
        ]
        if header:
            lines += [f"# {line}" for line in header.splitlines()]
        text = "\n".join(lines) + "\n" + yaml.safe_dump(self.to_dict(), sort_keys=False)
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_yaml(cls, path: str | Path, require: tuple[str, ...] = ()) -> "MembraneParameters":
        """Load and validate a parameters YAML file (``require``: see :meth:`from_dict`).

        The file may hold the fields at the top level or under a ``membrane:``
        key (so a params file can carry other sections too).
        """
        path = Path(path)
        data = read_yaml_mapping(path, ParameterError, "parameters file",
                                 fix=f"give a YAML path or a preset name {PRESET_NAMES}",
                                 mapping="a mapping of field: value (or a 'membrane:' section of them)")
        if "membrane" in data and isinstance(data["membrane"], Mapping):
            data = data["membrane"]
        return cls.from_dict(data, source=str(path), require=require)


def config_dir() -> Path:
    """The package's config folder: source tree, colcon/pip install (share/dea_ros/config), or ament index."""
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / "config"]  # source tree: <repo>/dea_ros/model/parameters.py
    # installed: <prefix>/lib/pythonX.Y/site-packages/dea_ros/model/parameters.py -> <prefix>/share/dea_ros/config
    candidates += [parent / "share" / "dea_ros" / "config" for parent in here.parents]
    if get_package_share_directory is not None:  # a sourced ROS 2 workspace
        try:
            candidates.append(Path(get_package_share_directory("dea_ros")) / "config")
        except Exception:  # noqa: BLE001 - dea_ros not in the ament index
            pass
    candidates.append(Path(sys.prefix) / "share" / "dea_ros" / "config")
    for c in candidates:
        if (c / "membranes").is_dir():
            return c
    raise FileNotFoundError(
        "dea_ros config folder (with membranes/) not found; looked in "
        + ", ".join(str(c) for c in candidates[:4]) + " ...; reinstall the package or pass a YAML path"
    )


def preset_path(name: str) -> Path:
    """Path of a preset membrane YAML (LP1, A1, A2)."""
    key = name.strip().upper()
    if key not in PRESET_NAMES:
        raise ParameterError(f"unknown membrane preset {name!r}; choose one of {PRESET_NAMES}")
    return config_dir() / "membranes" / f"{key}.yaml"


def preset(name: str, require: tuple[str, ...] = ()) -> MembraneParameters:
    """The paper's membrane LP1, A1 or A2 (Tables I-II, mass 3 g)."""
    return MembraneParameters.from_yaml(preset_path(name), require=require)


def load_parameters(name_or_path: str | Path, require: tuple[str, ...] = ()) -> MembraneParameters:
    """A preset name (LP1, A1, A2) or a path to a parameters YAML (``require``: fields that
    must be stated in the file even though they have a default, see :meth:`MembraneParameters.from_dict`)."""
    text = str(name_or_path)
    if Path(text).is_file():
        return MembraneParameters.from_yaml(text, require=require)
    looks_like_path = any(c in text for c in "/\\") or text.endswith((".yaml", ".yml"))
    if not looks_like_path:
        return preset(text, require=require)
    return MembraneParameters.from_yaml(text, require=require)
