"""A step record simulated at given parameters: the collocation solver of its samples (eqs. 1-12 with
the record's mass and voltage hold) on a grid fine enough for the membrane
(:meth:`~dea_ros.solvers.transient.TransientCollocation.for_record`). One place for what the fit, the
evaluation, the curvature sensitivity and the report's solver check all do with a step."""
from __future__ import annotations

import numpy as np

from ..model.parameters import MembraneParameters
from ..solvers.transient import TransientCollocation
from .experiments import StepData


def step_solver(params: MembraneParameters, step: StepData) -> TransientCollocation:
    """The solver of ``step``: its samples and voltage hold, the grid chosen for ``params`` with the
    record's mass (a fit keeps the grid for its later trial parameters)."""
    return TransientCollocation.for_record(params.replace(mass_kg=step.mass_kg), step.time_s, step.voltage_V,
                                           hold=step.voltage_hold)


def simulate_step(params: MembraneParameters, step: StepData) -> np.ndarray:
    """The displacement d (m) at the record's samples, simulated from the record's first sample at
    ``params`` with the record's mass."""
    p = params.replace(mass_kg=step.mass_kg)
    return step_solver(p, step).solve(p).displacement_m
