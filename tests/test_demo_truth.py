"""The demo's true counts per count row: a lane's true vehicles cross its lines one way only."""

import numpy as np
import pandas as pd

from trafficgeo.demo import true_line_counts


def test_a_crossing_seen_against_the_traffic_has_no_true_vehicle() -> None:
    # truth: three vehicles on d2_2 (direction 2, lane 2) and one on d1_1 cross line 3; one on d2_2 after the interval
    truth = pd.DataFrame({"line": [3, 3, 3, 3, 3], "direction": [2, 2, 2, 1, 2], "lane": [2, 2, 2, 1, 2],
                          "time": [1.0, 20.0, 59.0, 30.0, 61.0]})
    # the scenario's mapping: d2_2 is crossed +1 at line 3; the -1 crossing has no SUMO lane of its direction
    mapping = pd.DataFrame({"line": ["3", "3", "3"], "lane": ["d2_2", "d2_2", "d1_1"], "direction": [1, -1, -1],
                            "problem": ["", "no SUMO lane of this direction under the observed lane", ""]})
    rows = pd.DataFrame({"line": [3, 3, 3, 3], "lane": ["d2_2", "d2_2", "d1_1", "d1_1"], "direction": [-1, 1, -1, -1],
                         "interval_start": [0.0, 0.0, 0.0, 60.0], "interval_end": [60.0, 60.0, 60.0, 120.0]})
    np.testing.assert_array_equal(true_line_counts(rows, truth, mapping), [0, 3, 1, 0])
