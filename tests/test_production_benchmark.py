"""benchmarks/production.py's equal-error arithmetic: the samples Cycles needs to reach an
error, interpolated log-log on its curve and extrapolated beyond it as noise falls."""
import importlib.util
import os

import numpy as np
import pytest

PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks",
                    "production.py")
spec = importlib.util.spec_from_file_location("production_benchmark", PATH)
production = importlib.util.module_from_spec(spec)
spec.loader.exec_module(production)


def test_samples_to_reach_interpolates_and_extrapolates_as_noise_falls():
    curve = [(1, 0.4), (4, 0.2), (16, 0.1), (64, 0.05)]       # error ~ spp^-1/2
    n, extrapolated = production.samples_to_reach(0.1, curve)
    assert n == pytest.approx(16.0) and not extrapolated
    n, extrapolated = production.samples_to_reach(0.2 / np.sqrt(2.0), curve)
    assert n == pytest.approx(8.0) and not extrapolated        # log-log between 4 and 16
    n, extrapolated = production.samples_to_reach(0.025, curve)
    assert n == pytest.approx(256.0) and extrapolated          # beyond the curve: (0.05/0.025)^2
    n, extrapolated = production.samples_to_reach(0.9, curve)
    assert n == 1.0 and not extrapolated                        # worse than Cycles' cheapest
    assert production.samples_to_reach(None, curve) == (None, False)
    assert production.samples_to_reach(0.1, []) == (None, False)
