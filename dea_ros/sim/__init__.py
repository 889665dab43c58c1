"""The simulated rig (no ROS): what mock_hardware_node, ``dea-ros rig up`` and the closed-loop simulation run.

One of each::

    sim/
      plant.py                RigPlant: the membrane (the model by the core's RK4, the voltage held) and the
                              laser head (noise, quantisation): the one plant of mock_hardware_node and
                              dea_ros.control.simulation
      rig_simulator.py        RigSimulator: the plant on a clock (voltages applied at their send time, laser
                              readings with latency, thread-safe); LaserSampler: readings at a fixed rate
      amplifier_receiver.py   MockAmplifierReceiver: the amplifier's output stage (UDP from the mock backend,
                              dead-man interlock)
      ild1320_device.py       ILD1320Device: the laser sensor's settings, commands and stream, without a port
      ild1320_emulator.py     ILD1320Emulator: the device on a pseudo-terminal (what laser_sensor_node reads)
      mock_sensor.py          MockDisplacementSensor: the sensor's samples without a port (backend ``mock``)

The faults tests inject (garbage, corrupted frames, silence, wrong replies) are test doubles in test/fakes/.
"""
from .amplifier_receiver import MockAmplifierReceiver, ReceivedVoltage, free_udp_port
from .ild1320_device import DisplacementSource, ILD1320Device
from .ild1320_emulator import DEFAULT_SYMLINK_PATH, ILD1320Emulator
from .mock_sensor import MockDisplacementSensor
from .plant import LASER_QUANTISATION_M, RigPlant
from .rig_simulator import LaserSampler, RigSimulator

__all__ = [
    "RigPlant", "LASER_QUANTISATION_M", "RigSimulator", "LaserSampler", "MockAmplifierReceiver", "ReceivedVoltage",
    "free_udp_port",
    "ILD1320Device", "DisplacementSource", "ILD1320Emulator", "DEFAULT_SYMLINK_PATH", "MockDisplacementSensor",
]
