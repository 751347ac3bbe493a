"""A vehicle's class completed by its measured length (trafficgeo.traffic.measurements.classes_by_length): the
detector's size rule judges a box along the line of sight and leaves a bus seen broadside unknown; the track's
length, fitted with its heading, tells it."""

from __future__ import annotations

import numpy as np

from trafficgeo.geo.cuboids import VEHICLE_DIMENSIONS
from trafficgeo.traffic.measurements import classes_by_length


def test_unknown_vehicles_take_the_class_of_their_length_and_long_cars_become_trucks() -> None:
    cls = np.array(["", "", "", "", "car", "van", "car", "truck", "", "", "bus"], dtype=object)
    length = np.array([4.5, 6.0, 12.0, 2.0, 12.5, 9.0, 7.0, 12.0, np.nan, 12.0, 4.0])
    std = np.array([0.2, 0.3, 0.3, 0.1, 0.3, 0.5, 0.2, 0.3, np.nan, 3.0, 0.2])
    out = classes_by_length(cls, length, std)
    assert list(out) == ["car", "van", "truck", "", "truck", "truck", "car", "truck", "", "", "bus"]
    assert list(cls) == ["", "", "", "", "car", "van", "car", "truck", "", "", "bus"]  # the input is left as it was


def test_the_typical_sizes_of_the_classes_are_given_back_their_class() -> None:
    for name, expect in (("car", "car"), ("van", "van"), ("truck", "truck"), ("bus", "truck")):
        if name not in VEHICLE_DIMENSIONS:
            continue
        length = VEHICLE_DIMENSIONS[name][0]
        assert classes_by_length(np.array([""], dtype=object), np.array([length]), np.array([0.2]))[0] == expect
