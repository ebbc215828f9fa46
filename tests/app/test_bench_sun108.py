"""bench/bench_sun108.py's sun comparison: angle and strength ratio against analytic cases."""
import json

import numpy as np

from bench.bench_sun108 import estimated_sun, sun_error


def test_sun_error_angle_and_strength():
    true = {"direction_to_sun": [0.0, 1.0, 0.0], "irradiance_perpendicular": [10.0, 10.0, 10.0]}
    tilt = np.radians(3.0)
    est = {"direction_to_sun": [2 * np.sin(tilt), 2 * np.cos(tilt), 0.0],  # not unit: the angle is scale-free
           "irradiance_perpendicular": [11.0, 10.5, 11.5]}
    e = sun_error(est, true)
    assert abs(e["angle_deg"] - 3.0) < 1e-9
    assert abs(e["strength_ratio"] - 1.1) < 1e-12
    assert sun_error(None, true) == {"angle_deg": None, "strength_ratio": None}


def test_estimated_sun_reads_composite_report(tmp_path):
    (tmp_path / "report.json").write_text(json.dumps({"sun": {"from": "estimate", "direction": [0, 1, 0],
                                                              "irradiance_perpendicular": [1, 2, 3]}}))
    s = estimated_sun(tmp_path)
    assert s == {"direction_to_sun": [0, 1, 0], "irradiance_perpendicular": [1, 2, 3]}
    (tmp_path / "report.json").write_text(json.dumps({"sun": None}))
    assert estimated_sun(tmp_path) is None
    assert estimated_sun(tmp_path / "missing") is None
