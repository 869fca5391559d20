"""Trajectory corrections (seed 001) on a reduced sim6_turn, checked against the simulator's truth.

The full-size figures (seed: cloud-to-cloud 13.36 cm -> 6 mm) are in benchmarks/bench_calibrate.py.
The trajectory's common translation (and, with pose corrections, common rotation) is a gauge the
data cannot see: it is named unobservable, and the cloud is compared with truth once it is removed.
"""

import numpy as np
import pytest

import graphcal
from graphcal.recording.geodesy import to_world
from graphcal.simulation.script import load_scenario_builder

SIM6 = load_scenario_builder("sim6_turn")


@pytest.fixture(scope="module")
def piecewise_error():
    return graphcal.simulate(SIM6(size=0.02, seed=4), quiet=True)


def test_translation_corrections_remove_the_piecewise_error(piecewise_error):
    recording = piecewise_error
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="trajectory", stopping={"max_outer_iterations": 20}),
                                quiet=True)
    assert result.unobservable == ("trajectory.common_translation",)
    evaluation = graphcal.evaluate(result, recording)
    assert evaluation.cloud_before.mean > 0.10 and evaluation.cloud_after_gauge_free.mean < 0.006, evaluation.table()
    # each control's correction is the INS error there, up to the common translation
    times = result.calibration.control_times_s
    inside = (times >= recording.world.poses.span[0]) & (times <= recording.world.poses.span[1])
    true_position, _ = to_world(recording.truth.trajectory, recording.crs).poses.interpolate(times[inside])
    recorded_position, _ = recording.world.poses.interpolate(times[inside])
    error = (np.array([c.translation() for c in result.calibration.estimate.corrections])[inside]
             - (true_position - recorded_position))
    assert np.abs(true_position - recorded_position).max() > 0.2
    np.testing.assert_allclose(error - error.mean(axis=0), 0.0, atol=0.01)


def test_an_ins_heading_error_needs_pose_corrections():
    """A 0.5 deg INS heading error turns every scan about the vehicle: translation corrections can
    only make the cloud consistent by turning it as a whole (it stays centimetres off), pose
    corrections turn the scans back."""
    recording = graphcal.simulate(SIM6(size=0.02, seed=5, piecewise_error_m=0.0, heading_error_deg=0.5), quiet=True)
    after = {}
    for pose in (False, True):
        config = graphcal.CalibrationConfig(mode="trajectory", trajectory={"pose_corrections": pose},
                                            stopping={"max_outer_iterations": 15})
        result = graphcal.calibrate(recording, config, quiet=True)
        after[pose] = graphcal.evaluate(result, recording)
    assert after[False].cloud_before.mean > 0.05
    assert after[False].cloud_after_gauge_free.mean > 0.03, after[False].table()
    assert after[True].cloud_after_gauge_free.mean < 0.006, after[True].table()
