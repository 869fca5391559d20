"""Locating structure in a residual field (graphcal.diagnosis.locate) on a synthetic field whose
structure is known: a range-proportional error is found in the range bins, with its size and sign,
and the other regressors stay quiet."""

from types import SimpleNamespace

import numpy as np

from graphcal.diagnosis.locate import locate

N = 20_000


def _fit(rng):
    """N pairs on planes facing the sensor (normal along the beam), the residual 1 cm x range / 40 m
    plus 2 mm noise; fibre, azimuth and time drawn independently of it."""
    range_m = rng.uniform(5, 40, N)
    azimuth = rng.uniform(0, 2 * np.pi, N)
    beam = np.column_stack([np.cos(azimuth), np.sin(azimuth), np.zeros(N)])
    p = beam * range_m[:, None]
    residual = 0.01 * range_m / 40 + rng.normal(0, 0.002, N)
    m = p - residual[:, None] * beam  # p behind the surface by the residual, seen from the sensor
    time_s = np.sort(rng.uniform(0, 5, N))
    index = np.arange(N)
    points = np.vstack([p, m])
    data = SimpleNamespace(fibre=rng.integers(0, 32, 2 * N), azimuth_rad=np.r_[azimuth, azimuth],
                           range_m=np.r_[range_m, range_m], X_nav=np.zeros((2 * N, 3)), rows=np.arange(2 * N),
                           time_s=np.r_[time_s, time_s], sensor=SimpleNamespace(rotation_hz=10.0))
    context = SimpleNamespace(velocity=np.tile([8.0, 0, 0], (2 * N, 1)), omega=np.zeros((2 * N, 3)),
                              sweep_s=data.azimuth_rad / (2 * np.pi * 10.0), elapsed_s=data.time_s,
                              cos_incidence=np.ones(2 * N), range_m=data.range_m)
    pairs = SimpleNamespace(index_p=index, index_m=index + N, normal=-beam)  # normals of either sign
    cluster = (time_s / 0.05).astype(int)
    return SimpleNamespace(data=data, pairs=pairs, points_m=points, model=SimpleNamespace(context=context),
                           recording=SimpleNamespace(points=SimpleNamespace(
                               take=lambda columns, rows: {"intensity": rng.uniform(0, 255, len(rows))})),
                           clusters=lambda: (cluster, cluster % 2))


def test_a_range_proportional_error_is_located_in_the_range_bins():
    found = locate(_fit(np.random.default_rng(0)))
    bins = [row for row in found if "bin" in row]
    assert bins and {row["regressor"] for row in bins} <= {"range_m"}, bins
    far = max(bins, key=lambda row: row["bin"][0])
    near = min(bins, key=lambda row: row["bin"][0])
    mean_cm = 1.0 * 22.5 / 40  # the field's mean residual: the effects are relative to it
    assert abs(far["effect_cm"] - (np.mean(far["bin"]) / 40 - mean_cm)) < 0.1
    assert abs(near["effect_cm"] - (np.mean(near["bin"]) / 40 - mean_cm)) < 0.1
    assert far["effect_cm"] > 0 > near["effect_cm"]
    assert {row["regressor"] for row in found if "bin" not in row} == {"whiteness_time_s", "whiteness_azimuth_deg"}
