"""The DEA model: parameters (Tables I-II), dynamics (eqs. 1-12, 17-18), static equilibria, settle times (the
slowest time constant of the linearised eqs. 5-12)."""
from .dynamics import DEAModel
from .equilibrium import NoEquilibriumError, StaticEquilibrium, static_equilibrium, static_state
from .parameters import (
    PRESET_NAMES,
    MembraneParameters,
    ParameterError,
    config_dir,
    load_parameters,
    preset,
    preset_path,
)
from .settling import SettleTime, settle_time, slowest_time_constant_s

__all__ = [
    "DEAModel", "MembraneParameters", "ParameterError", "PRESET_NAMES", "preset", "preset_path",
    "config_dir", "load_parameters", "static_equilibrium", "static_state", "StaticEquilibrium",
    "NoEquilibriumError", "SettleTime", "settle_time", "slowest_time_constant_s",
]
