"""Kalman + RTS smoothing of world trajectories: speed accuracy, outliers, gaps, acceleration, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from trafficgeo.errors import InputError
from trafficgeo.traffic.smoothing import smooth_track


def test_constant_speed_is_recovered_far_better_than_the_noise():
    rng = np.random.default_rng(0)
    t = np.arange(0, 8, 0.04)
    heading = np.radians(30.0)
    truth = np.column_stack([245000 + 15.0 * t * np.sin(heading), 5182600 + 15.0 * t * np.cos(heading)])
    noisy = truth + rng.normal(0, 0.3, truth.shape)
    sm = smooth_track(t, noisy, 0.3)
    assert abs(sm.speed[10:-10].mean() * 3.6 - 54.0) < 0.3  # km/h
    assert np.sqrt(np.mean((np.column_stack([sm.x, sm.y]) - truth) ** 2)) < 0.3 / 3
    assert np.allclose(sm.heading_deg[5:-5], 30.0, atol=2.5)  # lateral velocity noise at 15 m/s
    # The reported speed uncertainty is of the size of the actual speed errors.
    err = np.abs(sm.speed - 15.0)[10:-10]
    assert 0.3 < np.sqrt(np.mean(err**2)) / np.median(sm.speed_std[10:-10]) < 3.0
    assert sm.outlier.sum() <= 2  # the 99.9 % gate: about one false alarm per thousand points


def test_outliers_are_rejected_and_gaps_bridged():
    rng = np.random.default_rng(1)
    t = np.concatenate([np.arange(0, 3, 0.04), np.arange(4, 7, 0.04)])  # a 1 s gap
    truth = np.column_stack([12.0 * t, np.zeros_like(t)])
    noisy = truth + rng.normal(0, 0.2, truth.shape)
    noisy[30] += [6.0, 4.0]  # a wrong detection / ID switch
    sm = smooth_track(t, noisy, 0.2)
    assert sm.outlier[30] and sm.outlier.sum() <= 2
    assert np.hypot(sm.x[30] - truth[30, 0], sm.y[30] - truth[30, 1]) < 0.3
    assert np.all(np.abs(sm.speed - 12.0) < 0.8)


def test_acceleration_along_the_track():
    t = np.arange(0, 6, 0.04)
    x = 10.0 * t + 0.5 * 2.0 * t**2
    rng = np.random.default_rng(2)
    sm = smooth_track(t, np.column_stack([x, np.zeros_like(x)]) + rng.normal(0, 0.1, (t.size, 2)), 0.1,
                      accel_sigma=2.0)
    assert abs(np.median(sm.accel[20:-20]) - 2.0) < 0.3
    np.testing.assert_allclose(sm.speed[20:-20], 10.0 + 2.0 * t[20:-20], atol=0.6)


def test_bad_tracks_are_refused():
    with pytest.raises(InputError, match="increase strictly"):
        smooth_track([0, 1, 1], [[0, 0], [1, 1], [2, 2]])
    with pytest.raises(InputError, match="one \\(x, y\\) per time"):
        smooth_track([0, 1], [[0, 0]])
    with pytest.raises(InputError, match="positive"):
        smooth_track([0, 1], [[0, 0], [1, 1]], sigma=0.0)
    single = smooth_track([0.0], [[5.0, 6.0]])
    assert single.x[0] == 5.0 and single.accel[0] == 0.0
