"""The simulated rig's plant: the membrane with its mass and the laser head that measures it (no ROS).

One implementation for both simulations of the rig: mock_hardware_node's
(:class:`~dea_ros.sim.rig_simulator.RigSimulator`, on a clock) and the closed-loop simulation
(:func:`~dea_ros.control.simulation.run_closed_loop`, step by step). The membrane is the model
(eq. 18) with its own, "true" parameters, integrated by the core's fixed-step RK4
(:class:`~dea_ros.solvers.integrate.RealTimeStepper`) with the voltage held over each physics
step (zero-order hold, as the amplifier's DAQ holds it). The laser reading adds Gaussian noise to
the displacement, then quantises it to the head's digital resolution.
"""
from __future__ import annotations

import numpy as np

from ..model.parameters import MembraneParameters
from ..solvers.integrate import RealTimeStepper

__all__ = ["RigPlant", "LASER_QUANTISATION_M"]

#: ILD1320-10 resolution, m: 10 mm x 1.02 / 65520 per digital step (config/mock_hardware.yaml's
#: ``quantisation_m``). Written as this product, which rounds one ulp away from
#: :func:`~dea_ros.hardware.laser.ild1320_protocol.frames.quantum_m`: the value both simulations
#: have always used.
LASER_QUANTISATION_M = 10e-3 * 1.02 / 65520


class RigPlant:
    """The membrane and the laser head of the simulated rig (SI units).

    * ``params``: the membrane's "true" parameters; ``physics_dt_s``: the RK4 step, s;
    * ``noise_m``: standard deviation of the laser's Gaussian noise, m (0: none);
    * ``quantisation_m``: the laser's digital resolution, m (0: none);
    * ``seed``: of the noise's random generator; ``initial_voltage_V``: the membrane starts at
      rest (static equilibrium) at this voltage.
    """

    def __init__(self, params: MembraneParameters, physics_dt_s: float, *, noise_m: float = 0.0,
                 quantisation_m: float = LASER_QUANTISATION_M, seed: int = 0,
                 initial_voltage_V: float = 0.0) -> None:
        self.params = params
        self.physics_dt_s = physics_dt_s
        self.noise_m = noise_m
        self.quantisation_m = quantisation_m
        self.stepper = RealTimeStepper(params, dt_s=physics_dt_s, initial_voltage_V=initial_voltage_V)
        self.rng = np.random.default_rng(seed)

    @property
    def displacement_m(self) -> float:
        """The membrane's displacement now, m."""
        return self.stepper.displacement_m

    def step(self, voltage_V: float) -> float:
        """Advance one physics step with ``voltage_V`` held; return the displacement, m."""
        return self.stepper.step(voltage_V)

    def laser_reading_m(self, displacement_m: float) -> float:
        """What the laser reads for ``displacement_m``: noise, then quantisation, m."""
        d = displacement_m
        if self.noise_m > 0:
            d += float(self.rng.normal(0.0, self.noise_m))
        if self.quantisation_m > 0:
            d = round(d / self.quantisation_m) * self.quantisation_m
        return d
