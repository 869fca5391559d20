"""The head's range noise measured from its own returns (graphcal.recording.range_noise) and what it decides."""

from dataclasses import replace

import numpy as np
import pytest

import graphcal
from graphcal.calibration.returns import initial_estimate, prepare, sight_at, world_at
from graphcal.recording.range_noise import FOURTH_DIFFERENCE, NOISY_ABOVE_M, measured_range_noise_m
from graphcal.simulation.script import load_scenario_builder


def _wall_sweep(noise_m: float, rng: np.random.Generator, kept: float = 1.0) -> tuple[np.ndarray, ...]:
    """Two fibres, interleaved in firing order, sweeping a wall 8 m away at two heights, plus a
    doorway 1 m deep (edges): fibres, ranges [m] and azimuths [rad] of a full-density HDL-32E azimuth step
    (0.16 deg), each firing kept with probability `kept` (a recording thinned unevenly)."""
    azimuth = np.radians(np.arange(-60, 60, 0.16))
    azimuth = azimuth[rng.random(len(azimuth)) < kept]
    depth = np.where(np.abs(azimuth - 0.3) < 0.05, 9.0, 8.0)
    ranges = [depth / np.cos(azimuth) / np.cos(np.radians(e)) for e in (-10.0, 5.0)]
    fibre = np.tile([3, 7], len(azimuth))
    range_m = np.column_stack(ranges).ravel() + rng.normal(0, noise_m, 2 * len(azimuth))
    return fibre, range_m, np.repeat(azimuth, 2)


@pytest.mark.parametrize("noise_m", [0.002, 0.01, 0.03])
def test_measured_range_noise_is_the_gaussian_sigma(noise_m):
    estimates = [measured_range_noise_m(*_wall_sweep(noise_m, np.random.default_rng(seed))) for seed in range(5)]
    # 1500 differences a draw: the median's relative spread is ~4 %
    assert np.mean(estimates) == pytest.approx(noise_m, rel=0.05)


def test_firings_dropped_unevenly_measure_the_same_noise():
    """A fifth of the firings kept at random: the divided difference in azimuth still cancels the wall's shape
    (1 / cos of the azimuth), where the plain fourth difference of the same ranges takes the uneven spacing for
    noise."""
    sweeps = [_wall_sweep(0.01, np.random.default_rng(seed), kept=0.2) for seed in range(20)]
    assert np.mean([measured_range_noise_m(*sweep) for sweep in sweeps]) == pytest.approx(0.01, rel=0.1)
    fibre, range_m, _ = sweeps[0]
    plain = np.lib.stride_tricks.sliding_window_view(range_m[fibre == 3], 5) @ FOURTH_DIFFERENCE
    assert 1.4826 * np.median(np.abs(plain)) > 0.02


def test_noise_free_surfaces_measure_no_noise_despite_edges():
    assert measured_range_noise_m(*_wall_sweep(0.0, np.random.default_rng(0))) < 1e-5
    assert measured_range_noise_m(*_wall_sweep(0.0, np.random.default_rng(0), kept=0.2)) < 1e-4


def test_too_few_returns_leave_the_noise_unknown():
    fibre, range_m, azimuth = _wall_sweep(0.01, np.random.default_rng(0))
    assert np.isnan(measured_range_noise_m(fibre[:60], range_m[:60], azimuth[:60]))
    assert np.isnan(measured_range_noise_m(fibre[:3], range_m[:3], azimuth[:3]))  # fewer than five: no difference
    # five ranges of one fibre at one azimuth (a dual return's) make no difference either
    assert np.isnan(measured_range_noise_m(np.full(500, 3), range_m[:500], np.zeros(500)))


def test_stand_ins_only_for_a_noisy_head():
    """m is chosen by stand-ins only when the range noise is at least NOISY_ABOVE_M (or unknown)."""

    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.1, seed=0), quiet=True)
    data, estimate, points = _at(recording)
    assert data.range_noise_m < NOISY_ABOVE_M  # noise-free: measured as such
    assert sight_at(data, estimate) is None
    for noise_m in (NOISY_ABOVE_M, np.nan):
        sight = sight_at(replace(data, range_noise_m=noise_m), estimate)
        assert sight is not None and sight.stand_ins(points).shape == points.shape
    noisy = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.1, seed=0, range_noise_m=0.01), quiet=True)
    assert sight_at(*_at(noisy)[:2]) is not None


def _at(recording):
    """(data of 20 k returns, the nominal estimate, its world points)."""
    data = prepare(recording, 1.0, 20_000)
    estimate = initial_estimate(recording, data)
    return data, estimate, world_at(data, estimate, False)
