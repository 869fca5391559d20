"""Moving traffic: movers where their paths say at each return's own time, the traffic's share of the
returns, bad specs refused, and the calibration's rejection of pairs on moving objects."""

import numpy as np
import pytest
from pydantic import ValidationError

import graphcal
from graphcal.simulation.drive import Drive, straight
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.scene import Ground
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.traffic import Mover, TrafficSpec, cast_movers

SPEC = TrafficSpec(vehicles=4, pedestrians=6, seed=3, crossing_fraction=0.5)


def _on_some_box(points_m: np.ndarray, elapsed_s: np.ndarray, movers: list[Mover]) -> np.ndarray:
    """Per point [m, local frame]: how far [m] it lies from the surface of the nearest mover, each mover
    where its path puts it at the point's time elapsed_s [s]."""
    best = np.full(len(points_m), np.inf)
    for mover in movers:
        half = np.asarray(mover.size_m) / 2
        centre = np.column_stack([mover.position(elapsed_s), np.full(len(points_m), mover.base_z_m + half[2])])
        yaw = np.radians(mover.yaw_deg)
        to_box = np.array([[np.cos(yaw), np.sin(yaw), 0], [-np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        local = (points_m - centre) @ to_box.T
        outside = np.linalg.norm(np.maximum(np.abs(local) - half, 0.0), axis=1)
        inside = np.maximum(np.min(half - np.abs(local), axis=1), 0.0)
        best = np.minimum(best, outside + inside)
    return best


def test_movers_are_where_their_paths_say_at_each_returns_time():
    scenario = Scenario(name="traffic", duration_s=1.5, size=0.05, scene=[Ground(size_m=(300, 300))],
                        drive=Drive(segments=straight(40), speed_knots=[(0, 8.0)]), traffic=SPEC)
    recording = graphcal.simulate(scenario, quiet=True)
    moving = recording.truth.moving()
    world = recording.truth.world_points()[moving] - np.asarray(scenario.origin_m)
    elapsed = recording.points.read()["time"][moving] - scenario.start_time_s
    movers = graphcal.simulation.simulator.movers(scenario)
    assert len(movers) == 10 and moving.sum() > 500
    np.testing.assert_array_less(_on_some_box(world, elapsed, movers), 1e-4)  # on a box, at its own time
    # the faces across a vehicle's motion are off it 5 ms later: each return sees it at its own time
    vehicles = [m for m in movers if m.kind == "vehicle"]
    on_vehicle = _on_some_box(world, elapsed, vehicles) < 1e-4
    later = _on_some_box(world[on_vehicle], elapsed[on_vehicle] + 0.005, vehicles)
    assert on_vehicle.sum() > 300 and np.mean(later > 0.02) > 0.04
    static = recording.truth.world_points()[~moving] - np.asarray(scenario.origin_m)
    static_elapsed = recording.points.read()["time"][~moving] - scenario.start_time_s
    off_ground = static[:, 2] > 0.01  # the boxes stand on the ground
    assert _on_some_box(static[off_ground], static_elapsed[off_ground], movers).min(initial=1.0) > 1e-4


def test_cast_movers_sees_a_box_at_the_rays_own_time():
    mover = Mover(size_m=(4.0, 2.0, 1.5), knots=[(0.0, 10.0, 0.0), (1.0, 20.0, 0.0)])
    origins = np.zeros((3, 3)) + [0.0, 0.0, 0.75]
    directions = np.tile([1.0, 0.0, 0.0], (3, 1))
    distance, index, normal = cast_movers([mover], origins, directions, np.array([0.0, 0.5, 2.0]), 100.0)
    np.testing.assert_allclose(distance, [8.0, 13.0, 18.0])  # rear face 2 m behind the centre, still after 1 s
    np.testing.assert_array_equal(index, 0)
    np.testing.assert_allclose(normal, np.tile([-1.0, 0.0, 0.0], (3, 1)), atol=1e-12)


def test_street_traffic_puts_a_tenth_of_the_returns_on_moving_objects():
    scenario = load_scenario_builder("street_traffic")(size=0.02, seed=0)
    movers = graphcal.simulation.simulator.movers(scenario)
    kinds = [m.kind for m in movers]
    assert kinds.count("vehicle") == scenario.traffic.vehicles and kinds.count("pedestrian") == scenario.traffic.pedestrians
    fraction = graphcal.simulate(scenario, quiet=True).truth.moving().mean()
    assert 0.10 <= fraction <= 0.30, fraction


@pytest.mark.parametrize("change, message", [({"vehicles": -1}, "vehicles"),
                                             ({"oncoming_speed_m_s": (9.0, 3.0)}, "oncoming_speed_m_s"),
                                             ({"street_end_xy": (-100.0, 0.2)}, "1 m apart"),
                                             ({"cars": 3}, "cars")])
def test_bad_traffic_spec_is_refused(change, message):
    with pytest.raises(ValidationError, match=message):
        TrafficSpec(**change)
    with pytest.raises(ValidationError, match="times must increase"):
        Mover(knots=[(1.0, 0.0, 0.0), (0.5, 1.0, 0.0)])


def test_rejection_drops_pairs_on_a_moving_object_and_keeps_static_ones():
    """Fibre pair (0, 1) sees a static plane z = 0 (2 mm noise) and a car whose rear moved 0.5 m/s x 0.1 s
    along the normal between the two returns; fibre pair (1, 2) sees the plane 3 cm off as a whole (the
    calibration's error, not motion); one static pair off by 4 cm was seen by both fibres at once."""
    from graphcal.calibration.association import Correspondences
    from graphcal.calibration.moving import moving_pairs

    rng = np.random.default_rng(0)
    n = 200
    p = np.column_stack([rng.uniform(0, 10, (n, 2)), np.zeros(n)])
    m = p + np.column_stack([rng.normal(0, 0.05, (n, 2)), rng.normal(0, 0.002, n)])
    m[:10, 2] += 0.05  # on the car
    m[100:, 2] += 0.03  # fibre pair (1, 2): a common offset
    m[10, 2] += 0.04  # acquired together
    points = np.r_[p, m]
    fibre = np.r_[np.zeros(100, int), np.ones(100, int), np.ones(100, int), np.full(100, 2)]
    time_s = np.r_[np.zeros(n), np.full(n, 0.1)]
    time_s[n + 10] = 1e-6
    pairs = Correspondences(np.arange(n), np.arange(n, 2 * n), np.tile([0.0, 0.0, 1.0], (n, 1)), np.ones(n))
    rejected = moving_pairs(pairs, points, fibre, time_s, sigmas=5.0, speed_m_s=20.0)
    np.testing.assert_array_equal(np.flatnonzero(rejected), np.arange(10))
