"""Session-cached synthetic experiment sets and identification results (keeps the suite fast)."""
from __future__ import annotations

import pytest

from dea_ros.identify.experiments import load_experiment_set
from dea_ros.identify.pipeline import identify
from dea_ros.identify.synth import synthesize
from dea_ros.model import preset

#: Sine frequencies of the test data sets: the paper's fit frequencies (0.2, 8.3, 11.2, 40 Hz)
#: plus points around the resonance (8.9-10.1 Hz for the presets) -- fewer than the CLI default.
TEST_FREQUENCIES_HZ = (0.2, 2.0, 5.0, 8.3, 9.0, 9.5, 10.0, 10.5, 11.2, 14.0, 40.0)
NOISE_M = 1e-6


@pytest.fixture(scope="session")
def synthetic(tmp_path_factory):
    """get(name) -> (folder, ExperimentSet loaded from disk): 1 um noise, seed 7, written once."""
    cache = {}

    def get(name: str):
        if name not in cache:
            folder = tmp_path_factory.mktemp(f"synth_{name}")
            synthesize(preset(name), NOISE_M, folder, seed=7, sine_frequencies_Hz=TEST_FREQUENCIES_HZ,
                       series_frequencies_Hz=(2.0,))
            cache[name] = (folder, load_experiment_set(folder))
        return cache[name]

    return get


@pytest.fixture(scope="session")
def identified(synthetic):
    """get(name, mode) -> IdentificationResult; mode "paper" (defaults) or "noise"
    (weights="noise", all frequencies, sigma_h''(1) identified)."""
    cache = {}

    def get(name: str, mode: str = "paper"):
        key = (name, mode)
        if key not in cache:
            _folder, exp = synthetic(name)
            if mode == "paper":
                cache[key] = identify(exp)
            else:
                cache[key] = identify(exp, weights="noise", fit_frequencies_Hz="all")
        return cache[key]

    return get
