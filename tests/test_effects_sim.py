"""The simulator's effects added for the mismatch finder: spin rate, projection scale, fibre
horizontal offset. Each is checked against the truth the simulator writes."""

from dataclasses import replace

import numpy as np

from graphcal.recording.geodesy import to_world
from graphcal.recording.georeference import georeference
from graphcal.simulation.drive import Drive, straight
from graphcal.simulation.scenario import ExtrinsicSpec, Scenario
from graphcal.simulation.scene import Pole, street
from graphcal.simulation.simulator import simulate


def small(**changes) -> Scenario:
    base = {"name": "small", "duration_s": 0.8, "size": 0.1, "scene": street(80, 16) + [Pole(xy=(10.0, 4.0))],
            "drive": Drive(segments=straight(40), speed_knots=[(0, 10.0)]),
            "extrinsic": ExtrinsicSpec(error_lever_arm_m=(0.02, -0.03, 0.05))}
    base.update(changes)
    return Scenario(**base)


def truth_error(recording, time=None, sensor=None) -> np.ndarray:
    """|raw returns georeferenced with the true calibration and trajectory - true points| [m]."""
    points, truth = recording.points.read(), recording.truth
    poses = to_world(truth.trajectory, recording.crs).poses
    world = georeference(points["time"] if time is None else time, points["fibre"], points["range"],
                         points["azimuth"], sensor or recording.sensor, truth.extrinsic, poses, truth.intrinsics)
    return np.linalg.norm(world - truth.world_points(), axis=1)


def test_spin_rate_stamps_drift_within_the_revolution():
    error = 0.02
    rec = simulate(small(effects={"spin_rate": {"error": error}}), quiet=True)
    points = rec.points.read(["time", "azimuth"])
    within_s = points["azimuth"].astype(np.float64) / (2 * np.pi * rec.sensor.rotation_hz * (1 + error))
    assert truth_error(rec, time=points["time"] - error * within_s).max() < 1e-4
    assert truth_error(rec).max() > 0.01  # the stamps are off by up to 2 ms at 10 m/s
    assert rec.truth.effects["spin_rate"]["magnitude"] == error


def test_projection_scale_scales_the_recorded_trajectory_only():
    scale = 1e-3
    rec = simulate(small(effects={"projection_scale": {"scale": scale}}), quiet=True)
    recorded = rec.world.poses
    true = to_world(rec.truth.trajectory, rec.crs).poses.resample(recorded.time)
    np.testing.assert_allclose(recorded.position_m - recorded.position_m[0],
                               (1 + scale) * (true.position_m - true.position_m[0]), atol=1e-6)
    assert truth_error(rec).max() < 1e-4  # the true trajectory reproduces the cloud


def test_fibre_horizontal_offset_moves_returns_sideways():
    offset = 0.03
    rec = simulate(small(effects={"fibre_horizontal_offset": {"offset_m": offset}}), quiet=True)
    side = np.where(np.arange(rec.sensor.n_fibres) % 2 == 0, 1.0, -1.0)
    true_sensor = replace(rec.sensor, horizontal_offset_m=rec.sensor.horizontal_offset_m + offset * side)
    assert truth_error(rec, sensor=true_sensor).max() < 1e-4
    assert np.median(truth_error(rec)) > 0.5 * offset
