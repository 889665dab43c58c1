"""Experiments: what was measured on a membrane, as data, and its hand-writable on-disk format.

One concept per module:

* :mod:`.data` -- the data classes: :class:`StaticData`, :class:`StepData`, :class:`SineSeries`,
  :class:`SineData` and the whole :class:`ExperimentSet`;
* :mod:`.manifest` -- the on-disk format ``dea_ros.experiments/1`` (a folder with ``manifest.yaml``
  and CSV files; documented there): :func:`load_experiment_set`, :func:`write_experiment_set`;
* :mod:`.csv_io` -- the CSV files (unit-suffixed headers): :func:`read_csv_columns`, :func:`write_csv_columns`;
* :mod:`.checks` -- plausibility checks of the columns (units, lengths, finite values, increasing time);
* :mod:`.records` -- sampled records under a periodic voltage: whole periods, the RMS of eq. 21, the
  laser noise, the applied input;
* :mod:`.quality` -- data-quality warnings that do not prevent a fit.

Imports point down: data uses checks and records; manifest uses data, checks and csv_io; quality uses
data and records.
"""
from ...errors import ExperimentError
from .csv_io import read_csv_columns, write_csv_columns
from .data import GEOMETRY_FIELDS, WAVEFORMS, ExperimentSet, SineData, SineSeries, StaticData, StepData
from .manifest import FORMAT, KINDS, load_experiment_set, write_experiment_set
from .quality import data_warnings, estimate_noise_m, rest_warning, step_settling_warning
from .records import detrended_rms, period_weights, periodic_input_from_record, rms_statistics, third_difference_noise

__all__ = [
    "FORMAT",
    "KINDS",
    "WAVEFORMS",
    "GEOMETRY_FIELDS",
    "ExperimentError",
    "StaticData",
    "StepData",
    "SineSeries",
    "SineData",
    "ExperimentSet",
    "load_experiment_set",
    "write_experiment_set",
    "read_csv_columns",
    "write_csv_columns",
    "estimate_noise_m",
    "step_settling_warning",
    "rest_warning",
    "data_warnings",
    "period_weights",
    "rms_statistics",
    "periodic_input_from_record",
    "third_difference_noise",
    "detrended_rms",
]
