"""The on-disk format of an experiment set: a folder with ``manifest.yaml`` and CSV files.

On-disk format (``dea_ros.experiments/1``)
=========================================
One folder per data set::

    my_membrane/
      manifest.yaml
      static.csv
      step_2200V.csv
      sine_rms.csv
      sine_2Hz.csv          (optional sampled time series)

``manifest.yaml`` (every quantity in SI units; the ``units`` block is checked)::

    format: dea_ros.experiments/1
    membrane: A1                 # name given to the fitted parameters
    parameters: A1               # optional: preset name or a parameters YAML (relative to
                                 #   this folder): geometry, constants, Ogden prior
    geometry:                    # required when 'parameters' is absent; overrides it otherwise
      prestretch: 1.36           #   lambda_p (Table I)
      thickness_m: 2.7e-05       #   z0
      plate_radius_m: 0.0045     #   r
      electrode_width_m: 0.017   #   l0
    mass_kg: 0.003               # biasing mass of the step and sine experiments
    sensor_noise_m: 1.0e-06      # optional: laser noise sigma (otherwise estimated)
    units: {time: s, voltage: V, displacement: m, mass: kg, frequency: Hz}
    experiments:
      - kind: static             # columns mass_kg, voltage_V, displacement_m[, displacement_std_m] (one row
                                 #   per point; displacement_std_m: the standard uncertainty of the point's
                                 #   mean, the joint fit's weight of it)
        file: static.csv
      - kind: step               # columns time_s, voltage_V, displacement_m (sampled)
        file: step_2200V.csv
        voltage_hold: zoh        # optional: zoh (DAQ output, default) or linear
        mass_kg: 0.003           # optional: overrides the top-level mass for this experiment
      - kind: sine               # columns frequency_Hz, amplitude_V, d_rms_m[, d0_m, d_rms_std_m]
        file: sine_rms.csv       #   d_rms by eq. 21 around the rest position d0 over whole periods
                                 #   (laser noise removed, see rms_statistics); d_rms_std_m its
                                 #   standard uncertainty (statistical weights of the joint fit)
        waveform: sine           # the applied voltage: sine, u = U sin(2 pi f t) (the paper), or
                                 #   abs_sine, u = |U sin(2 pi f t)| (a unipolar amplifier, the rig);
                                 #   U = amplitude_V. Both give the same u^2, all the model sees (eq. 6)
        series:                  # optional sampled records: time_s, voltage_V (the applied u(t)),
          - {frequency_Hz: 2.0, file: sine_2Hz.csv}     # displacement_m, from phase 0 of the sine

CSV files: comma separated, ``#`` starts a comment line, the first other line
is the header. Every column name ends with its unit (``_s``, ``_V``, ``_m``,
``_kg``, ``_Hz``); columns not listed above are ignored. Displacement d is the
downward deflection of the mass from the flat membrane (d = 0 at 0 g, 0 V),
as in the paper (Fig. 1).

Loading validates units (header suffixes, values that look like mm or kV),
lengths, NaN/inf, strictly increasing time and the minimum amount of data;
every :class:`ExperimentError` names the file, the column and, where it
applies, the row (the 1-based line number in the file).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

from ...errors import ExperimentError
from ...model.parameters import PRESET_NAMES, MembraneParameters, ParameterError, load_parameters
from ...model.yaml_files import read_yaml_mapping
from .checks import check_displacement, check_mass, check_time, check_voltage
from .csv_io import read_csv_columns, write_csv_columns
from .data import GEOMETRY_FIELDS, WAVEFORMS, ExperimentSet, SineData, SineSeries, StaticData, StepData

__all__ = ["FORMAT", "KINDS", "STATIC_COLUMNS", "STATIC_OPTIONAL", "STEP_COLUMNS", "SINE_COLUMNS", "SINE_OPTIONAL",
           "load_experiment_set", "write_experiment_set"]

FORMAT = "dea_ros.experiments/1"
KINDS = ("static", "step", "sine")
_SI_UNITS = {"time": "s", "voltage": "V", "displacement": "m", "mass": "kg", "frequency": "Hz"}
#: Fields of manifest.yaml.
_FIELDS = {"format", "membrane", "parameters", "geometry", "mass_kg", "sensor_noise_m", "units", "experiments",
           "notes"}

#: Columns of each file type (sampled sine records have the columns of a step).
STATIC_COLUMNS = ("mass_kg", "voltage_V", "displacement_m")
STATIC_OPTIONAL = ("displacement_std_m",)
STEP_COLUMNS = ("time_s", "voltage_V", "displacement_m")
SINE_COLUMNS = ("frequency_Hz", "amplitude_V", "d_rms_m")
SINE_OPTIONAL = ("d0_m", "d_rms_std_m")


# --------------------------------------------------------------------------- reading
def _manifest_error(path: Path, msg: str) -> ExperimentError:
    return ExperimentError(f"{path}: {msg}")


def _resolve_parameters(folder: Path, ref: str, manifest: Path) -> MembraneParameters:
    candidate = folder / ref
    try:
        if candidate.is_file():
            return MembraneParameters.from_yaml(candidate)
        if ref.strip().upper() in PRESET_NAMES:
            return load_parameters(ref)
    except ParameterError as exc:
        raise _manifest_error(manifest, f"field 'parameters': {exc}") from None
    raise _manifest_error(
        manifest,
        f"field 'parameters': {ref!r} is neither a file in {folder} nor a preset {PRESET_NAMES}",
    )


def _read_manifest(manifest: Path) -> Mapping:
    """The manifest's mapping, its fields, format and units checked."""
    data = read_yaml_mapping(manifest, ExperimentError, "manifest",
                             mapping="a mapping (format, membrane, mass_kg, experiments, ...)")
    unknown = sorted(set(data) - _FIELDS)
    if unknown:
        raise _manifest_error(manifest, f"unknown field(s) {unknown}; allowed: {sorted(_FIELDS)}")
    fmt = data.get("format", FORMAT)
    if fmt != FORMAT:
        raise _manifest_error(manifest, f"field 'format': {fmt!r} is not supported (expected {FORMAT!r})")
    units = data.get("units", {}) or {}
    if not isinstance(units, Mapping):
        raise _manifest_error(manifest, "field 'units': expected a mapping such as {time: s, voltage: V}")
    for quantity, unit in units.items():
        if quantity not in _SI_UNITS:
            raise _manifest_error(manifest, f"field 'units.{quantity}': unknown quantity; known {sorted(_SI_UNITS)}")
        if str(unit) != _SI_UNITS[quantity]:
            raise _manifest_error(
                manifest,
                f"field 'units.{quantity}': '{unit}' is not supported; the format is SI "
                f"({quantity} in {_SI_UNITS[quantity]}): convert the CSV values and state "
                f"'{_SI_UNITS[quantity]}'",
            )
    return data


def _geometry(data: Mapping, base: MembraneParameters | None, manifest: Path) -> dict:
    """Table I's geometry: the base parameters' (if any), overridden by the manifest's ``geometry``."""
    geometry: dict[str, Any] = {}
    if base is not None:
        geometry.update({k: getattr(base, k) for k in GEOMETRY_FIELDS})
    extra_geometry = data.get("geometry") or {}
    if not isinstance(extra_geometry, Mapping):
        raise _manifest_error(manifest, "field 'geometry': expected a mapping of " + ", ".join(GEOMETRY_FIELDS))
    bad = sorted(set(extra_geometry) - set(GEOMETRY_FIELDS))
    if bad:
        raise _manifest_error(manifest, f"field 'geometry': unknown key(s) {bad}; allowed {list(GEOMETRY_FIELDS)}")
    for k, v in extra_geometry.items():
        try:
            geometry[k] = float(v)
        except (TypeError, ValueError):
            raise _manifest_error(manifest, f"field 'geometry.{k}': must be a number, got {v!r}") from None
    return geometry


def _static_from(path: Path) -> StaticData:
    cols = read_csv_columns(path, STATIC_COLUMNS, STATIC_OPTIONAL)
    lines = cols["_lines"]
    check_mass(cols["mass_kg"], "mass_kg", str(path), lines)
    check_voltage(cols["voltage_V"], "voltage_V", str(path), lines)
    check_displacement(cols["displacement_m"], "displacement_m", str(path), lines)
    return StaticData(cols["mass_kg"], cols["voltage_V"], cols["displacement_m"], str(path),
                      std_error_m=cols.get("displacement_std_m"))


def _step_from(path: Path, entry: Mapping, mass_kg) -> StepData:
    cols = read_csv_columns(path, STEP_COLUMNS)
    lines = cols["_lines"]
    check_time(cols["time_s"], "time_s", str(path), lines)
    check_displacement(cols["displacement_m"], "displacement_m", str(path), lines)
    return StepData(cols["time_s"], cols["voltage_V"], cols["displacement_m"], mass_kg=mass_kg,
                    voltage_hold=entry.get("voltage_hold", "zoh"), source=str(path))


def _sine_from(path: Path, entry: Mapping, mass_kg, folder: Path, manifest: Path, where: str) -> SineData:
    cols = read_csv_columns(path, SINE_COLUMNS, SINE_OPTIONAL)
    series = []
    for j, item in enumerate(entry.get("series", []) or []):
        if not isinstance(item, Mapping) or "file" not in item or "frequency_Hz" not in item:
            raise _manifest_error(manifest, f"{where}.series[{j}]: needs 'frequency_Hz' and 'file'")
        spath = folder / str(item["file"])
        scols = read_csv_columns(spath, STEP_COLUMNS)
        check_time(scols["time_s"], "time_s", str(spath), scols["_lines"])
        series.append(SineSeries(float(item["frequency_Hz"]), scols["time_s"], scols["voltage_V"],
                                 scols["displacement_m"], source=str(spath)))
    waveform = entry.get("waveform", "sine")
    if waveform not in WAVEFORMS:
        raise _manifest_error(manifest, f"{where}.waveform: {waveform!r} is not one of {WAVEFORMS} "
                                        "(sine: U sin(2 pi f t); abs_sine: |U sin(2 pi f t)|)")
    return SineData(cols["frequency_Hz"], cols["amplitude_V"], cols["d_rms_m"], mass_kg=mass_kg,
                    d0_m=cols.get("d0_m"), series=tuple(series), source=str(path),
                    d_rms_std_m=cols.get("d_rms_std_m"), waveform=waveform)


def _experiments(data: Mapping, folder: Path, manifest: Path, mass) -> tuple[list, list, list]:
    """(static, steps, sines) of the manifest's ``experiments`` list, each file loaded and checked."""
    entries = data.get("experiments")
    if not isinstance(entries, list) or not entries:
        raise _manifest_error(manifest, "field 'experiments': a non-empty list of {kind, file} is required")
    static, steps, sines = [], [], []
    for k, entry in enumerate(entries):
        where = f"experiments[{k}]"
        if not isinstance(entry, Mapping) or "kind" not in entry or "file" not in entry:
            raise _manifest_error(manifest, f"{where}: needs 'kind' ({'/'.join(KINDS)}) and 'file'")
        kind = entry["kind"]
        if kind not in KINDS:
            raise _manifest_error(manifest, f"{where}.kind: {kind!r} is not one of {KINDS}")
        path = folder / str(entry["file"])
        exp_mass = entry.get("mass_kg", mass)
        try:
            if kind == "static":
                static.append(_static_from(path))
            elif kind == "step":
                steps.append(_step_from(path, entry, exp_mass))
            else:
                sines.append(_sine_from(path, entry, exp_mass, folder, manifest, where))
        except ParameterError as exc:  # pragma: no cover - defensive
            raise ExperimentError(f"{path}: {exc}") from None
    return static, steps, sines


def load_experiment_set(folder: str | Path) -> ExperimentSet:
    """Load and validate an experiment folder (see the module docstring for the format)."""
    folder = Path(folder)
    manifest = folder / "manifest.yaml"
    if folder.is_file() and folder.name.endswith((".yaml", ".yml")):
        manifest, folder = folder, folder.parent
    if not manifest.is_file():
        raise ExperimentError(
            f"{folder}: no manifest.yaml; an experiment folder holds manifest.yaml and CSV files "
            "(see dea_ros.identify.experiments)"
        )
    data = _read_manifest(manifest)
    membrane = data.get("membrane")
    if not isinstance(membrane, str) or not membrane.strip():
        raise _manifest_error(manifest, "field 'membrane': a name is required (e.g. A1)")
    ref = data.get("parameters")
    base = None if ref is None else _resolve_parameters(folder, str(ref), manifest)
    geometry = _geometry(data, base, manifest)
    if "mass_kg" not in data:
        raise _manifest_error(manifest, "field 'mass_kg': the biasing mass (kg) is required (3 g -> 0.003)")
    mass = data["mass_kg"]
    if isinstance(mass, bool) or not isinstance(mass, (int, float)):
        raise _manifest_error(manifest, f"field 'mass_kg': must be a number in kg, got {mass!r}")
    noise = data.get("sensor_noise_m")
    static, steps, sines = _experiments(data, folder, manifest, mass)
    return ExperimentSet(
        membrane=membrane.strip(), geometry=geometry, mass_kg=float(mass), static=static,
        steps=steps, sines=sines, base_parameters=base,
        base_reference=None if ref is None else str(ref),
        sensor_noise_m=None if noise is None else float(noise), folder=folder,
        notes=str(data.get("notes", "") or ""),
    )


# --------------------------------------------------------------------------- writing
#: The first lines of a written manifest.yaml (the path in it names the format's former single module,
#: kept while the golden outputs of issue 24 compare manifests byte for byte).
_HEADER = (
    "# dea_ros experiment set (format dea_ros.experiments/1): SI units everywhere.\n"
    "# See dea_ros/identify/experiments.py for the format. d = downward deflection of the mass.\n"
)


def _write_static(experiments: ExperimentSet, folder: Path) -> list:
    entries = []
    for k, s in enumerate(experiments.static):
        name = "static.csv" if len(experiments.static) == 1 else f"static_{k}.csv"
        cols = {"mass_kg": s.mass_kg, "voltage_V": s.voltage_V, "displacement_m": s.displacement_m}
        if s.stated_std_m is not None:
            cols["displacement_std_m"] = s.stated_std_m
        write_csv_columns(folder / name, cols,
                          comment="static points: rest displacement for a mass and a constant voltage (eq. 20); "
                                  "displacement_std_m: the standard uncertainty of each mean (optional)")
        entries.append({"kind": "static", "file": name})
    return entries


def _write_steps(experiments: ExperimentSet, folder: Path) -> list:
    entries = []
    for k, s in enumerate(experiments.steps):
        name = f"step_{k}_{abs(s.final_V - s.initial_V):.0f}V.csv"
        write_csv_columns(folder / name, {"time_s": s.time_s, "voltage_V": s.voltage_V,
                                          "displacement_m": s.displacement_m},
                          comment=f"voltage step {s.initial_V:g} V -> {s.final_V:g} V, mass {s.mass_kg:g} kg")
        entry = {"kind": "step", "file": name, "voltage_hold": s.voltage_hold}
        if s.mass_kg != experiments.mass_kg:
            entry["mass_kg"] = s.mass_kg
        entries.append(entry)
    return entries


def _write_sines(experiments: ExperimentSet, folder: Path) -> list:
    entries = []
    for k, s in enumerate(experiments.sines):
        name = "sine_rms.csv" if len(experiments.sines) == 1 else f"sine_rms_{k}.csv"
        cols = {"frequency_Hz": s.frequency_Hz, "amplitude_V": s.amplitude_V, "d_rms_m": s.d_rms_m}
        if s.d0_m is not None:
            cols["d0_m"] = s.d0_m
        if s.d_rms_std_m is not None:
            cols["d_rms_std_m"] = s.d_rms_std_m
        write_csv_columns(folder / name, cols,
                          comment="frequency response: RMS of d - d0 over whole periods (eq. 21, interpolated "
                                  "period boundaries, laser noise removed); d_rms_std_m: its standard uncertainty "
                                  "(optional); excitation u = "
                                  f"{'|U sin(2 pi f t)|' if s.waveform == 'abs_sine' else 'U sin(2 pi f t)'}"
                                  ", U = amplitude_V")
        entry: dict[str, Any] = {"kind": "sine", "file": name, "waveform": s.waveform}
        if s.mass_kg != experiments.mass_kg:
            entry["mass_kg"] = s.mass_kg
        series = []
        for j, ser in enumerate(s.series):
            sname = f"sine_{k}_{j}_{ser.frequency_Hz:g}Hz.csv"
            write_csv_columns(folder / sname, {"time_s": ser.time_s, "voltage_V": ser.voltage_V,
                                               "displacement_m": ser.displacement_m},
                              comment=f"sine record at {ser.frequency_Hz:g} Hz")
            series.append({"frequency_Hz": float(ser.frequency_Hz), "file": sname})
        if series:
            entry["series"] = series
        entries.append(entry)
    return entries


def write_experiment_set(experiments: ExperimentSet, folder: str | Path) -> Path:
    """Write an experiment set as a folder (manifest.yaml + CSV files); return the manifest path.

    A base parameters object is written next to the manifest as ``base_parameters.yaml``
    (unless it was referenced by preset name).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {"format": FORMAT, "membrane": experiments.membrane}
    if experiments.base_parameters is not None:
        ref = experiments.base_reference
        if ref is not None and ref.strip().upper() in PRESET_NAMES:
            manifest["parameters"] = ref.strip().upper()
        else:
            experiments.base_parameters.to_yaml(folder / "base_parameters.yaml",
                                                header="base parameters of the experiment set")
            manifest["parameters"] = "base_parameters.yaml"
    manifest["geometry"] = {k: float(experiments.geometry[k]) for k in GEOMETRY_FIELDS}
    manifest["mass_kg"] = float(experiments.mass_kg)
    if experiments.sensor_noise_m is not None:
        manifest["sensor_noise_m"] = float(experiments.sensor_noise_m)
    manifest["units"] = dict(_SI_UNITS)
    manifest["experiments"] = (_write_static(experiments, folder) + _write_steps(experiments, folder)
                               + _write_sines(experiments, folder))
    if experiments.notes:
        manifest["notes"] = experiments.notes
    path = folder / "manifest.yaml"
    path.write_text(_HEADER + yaml.safe_dump(manifest, sort_keys=False))
    experiments.folder = folder
    return path
