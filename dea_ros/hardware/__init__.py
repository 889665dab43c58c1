"""Device protocols and backends of the rig (no ROS import): the high-voltage amplifier and the laser sensor.

One concept per file; the protocols are pure and unit-tested, the ROS nodes (dea_ros.nodes) are thin
adapters around them (as nmea_navsat_driver's parser.py and its node)::

    hardware/
      amplifier/                the high-voltage amplifier
        limits.py               SafetyLimits, fixed at start-up (maximum from the membrane's breakdown field)
        safety.py               SafeVoltageController (every output goes through it), drive_to_zero, ControlClock
        base.py                 AmplifierBackend, the interface of the backends
        inprocess.py            InProcessAmplifierBackend (in memory)
        udp.py                  the datagram format and MockAmplifierBackend (to the simulated rig)
        uldaq.py                UldaqAmplifierBackend (Measurement Computing DAQ; uldaq imported when used)
        rig_description.py      a DAQ board against what the configuration expects (pure)
        config.py               amplifier_node's parameters -> limits and hardware expectation
      laser/                    the laser displacement sensor
        base.py                 DisplacementSensor, DisplacementReading, MeasurementError
        ild1320_protocol/       the ILD1320's RS422 protocol (pure): frames, commands, settings
        plausibility.py         PlausibilityFilter (the stream has no checksum)
        sample_clock.py         SampleClock (acquisition times from the arrival times)
        ild1320_serial.py       ILD1320Sensor on a serial port (imports pyserial: import it where used)

The simulated devices (the amplifier's output stage, the ILD1320 emulator, the rig's physics) are
in :mod:`dea_ros.sim`; the test doubles that inject faults are in test/fakes/, out of the product.
"""
__all__: list[str] = []
