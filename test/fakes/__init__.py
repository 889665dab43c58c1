"""Test doubles, out of the product: load each module by path (the suite runs with --import-mode=importlib).

* ``faulty_ild1320.py``: the ILD1320 emulator with fault injection (garbage, corrupted frames,
  silence, wrong replies, ignored commands, byte faults) and the record of emitted samples;
* ``faulty_mock_sensor.py``: the serial-free mock sensor with a lost connection on request;
* ``fake_uldaq.py``: a stand-in for the ``uldaq`` package with the real boards' capabilities;
* ``amplifier_saboteur.py``: a process running amplifier_node next to a node that breaks it.
"""
