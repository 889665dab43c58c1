"""Membranes for tests, unlike the presets (test data, not doubles of a device).

``F07``: member F07 of the coverage family (``bench/bench_coverage_family.py``): softening at stretch 1
(sigma_h'(1) < 0), a slow creep, its upper branch folding at 12.0 Hz for a 2.5 kV sine.
``F17``: member F17 of the coverage family: creep time 1.85 s, resonance 9.29 Hz, the record at the
resonance on the upper branch where the model near the truth has a quasi-periodic response (test_left_static_points).
``F05``: member F05 of the coverage family: creep time 7.38 s, resonance 8.97 Hz; with 17 frequencies and noise
seed 1517422253 its joint refinement leaves the static points with no unreachable record to leave out
(test_rejected_refinement).
``F13``: member F13 of the coverage family: thin (26 um), heavy (5.5 g), creep time 0.08 s, resonance 7.39 Hz; its
two passes determine sigma_h''(1) to +-0.5 % and see the Ogden shape beyond it (test_held_shape).
"""
from dea_ros.model import preset

F07 = preset("A2").replace(
    name="F07", prestretch=1.2040504286613254, thickness_m=2.718577223977574e-05,
    plate_radius_m=0.004650763132756726, electrode_width_m=0.014088327367956255, mass_kg=0.0025537815941661887,
    relative_permittivity=3.3254410847486247, k1_Pa=46083050.2731271, eta1_Pa_s=610535480.0111244,
    eta2_Pa_s=12918.153146132565, beta_Pa=(-649423.5829986259, -470617.32024944725, 1002090.2299789758),
    gamma_Pa=(-251839.89282292488, -1008795.7008347407, 160775.06479202586))

F17 = preset("A2").replace(
    name="F17", prestretch=1.370434646953647, thickness_m=4.1150812811569506e-05,
    plate_radius_m=0.004277577271131438, electrode_width_m=0.014216683245441354, mass_kg=0.005035555024226549,
    relative_permittivity=2.889020518837167, k1_Pa=33282405.00507301, eta1_Pa_s=61591833.27546447,
    eta2_Pa_s=13800.981842594967, beta_Pa=(-542512.6313489117, -373543.3626669269, 824264.0615509768),
    gamma_Pa=(-102421.36120390776, -852803.6540932271, 69217.83417250344))

F05 = preset("A2").replace(
    name="F05", prestretch=1.1476227383389705, thickness_m=4.8220560675391296e-05,
    plate_radius_m=0.005007222424129883, electrode_width_m=0.015176958400785947, mass_kg=0.00531654402858023,
    relative_permittivity=3.0398337282972654, k1_Pa=36161300.55999581, eta1_Pa_s=267030297.71074435,
    eta2_Pa_s=7278.5810059329215, beta_Pa=(-608104.4283698774, -378234.81793036277, 844384.0095091542),
    gamma_Pa=(48422.94792962354, -750014.6681097824, 15225.448531533999))

F13 = preset("A2").replace(
    name="F13", prestretch=1.3690142419978857, thickness_m=2.5999681248192284e-05,
    plate_radius_m=0.005418121103718888, electrode_width_m=0.014618876463310075, mass_kg=0.005471065797404976,
    relative_permittivity=2.6073171996505904, k1_Pa=24042766.306119893, eta1_Pa_s=1810202.4818657807,
    eta2_Pa_s=23612.361685399614, beta_Pa=(-1090238.3837896073, -689060.4890614075, 1306945.5190321112),
    gamma_Pa=(36960.45646370103, -941370.0539335783, 11921.94561747578))
