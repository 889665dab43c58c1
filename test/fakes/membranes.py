"""Membranes for tests, unlike the presets (test data, not doubles of a device).

``F07``: member F07 of the coverage family (``bench/bench_coverage_family.py``): softening at stretch 1
(sigma_h'(1) < 0), a slow creep, its upper branch folding at 12.0 Hz for a 2.5 kV sine.
"""
from dea_ros.model import preset

F07 = preset("A2").replace(
    name="F07", prestretch=1.2040504286613254, thickness_m=2.718577223977574e-05,
    plate_radius_m=0.004650763132756726, electrode_width_m=0.014088327367956255, mass_kg=0.0025537815941661887,
    relative_permittivity=3.3254410847486247, k1_Pa=46083050.2731271, eta1_Pa_s=610535480.0111244,
    eta2_Pa_s=12918.153146132565, beta_Pa=(-649423.5829986259, -470617.32024944725, 1002090.2299789758),
    gamma_Pa=(-251839.89282292488, -1008795.7008347407, 160775.06479202586))
