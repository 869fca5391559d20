"""scenarios/city_loop.py: its route revisits the district's streets both ways, its INS drifts as stated,
and simulate_to writes it as it goes, the same recording as simulate + save, in several row groups."""

import filecmp
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from graphcal.recording.directory import Recording
from graphcal.simulation.ins_drift import ins_drift
from graphcal.common.errors import ConfigError
from graphcal.simulation.drive import spin, straight
from graphcal.simulation.route import looped_drive, street_circuit
from graphcal.simulation.scenario import SEED_002_ODOMETRY, InsErrors
from graphcal.simulation.script import SCENARIOS_DIR, load_scenario_builder
from graphcal.simulation.simulator import simulate, simulate_to

CITY = load_scenario_builder("city_loop")
PITCH_M, HALF_STREET_M = 56.0, 8.0  # the default district's crossing spacing and half street width


def street_passes(positions_m: np.ndarray, yaw_deg: np.ndarray) -> dict[tuple, list[tuple[int, int]]]:
    """{street (axis, line, segment): [(first sample index, direction +-1), ...]}, one entry per pass along
    the street between two crossings (samples in the crossings themselves are not counted)."""
    passes: dict[tuple, list[tuple[int, int]]] = {}
    previous = None
    for k, ((x, y), yaw) in enumerate(zip(positions_m[:, :2], yaw_deg)):
        axis = 0 if abs(np.cos(np.radians(yaw))) > 0.9 else 1 if abs(np.sin(np.radians(yaw))) > 0.9 else None
        along, across = (x, y) if axis == 0 else (y, x)
        offset = along % PITCH_M
        if axis is None or abs(across - PITCH_M * round(across / PITCH_M)) > 1.0 or not (
                HALF_STREET_M < offset < PITCH_M - HALF_STREET_M):
            previous = None
            continue
        street = (axis, round(across / PITCH_M), int(along // PITCH_M))
        if street != previous:
            direction = int(np.sign(np.cos(np.radians(yaw)) if axis == 0 else np.sin(np.radians(yaw))))
            passes.setdefault(street, []).append((k, direction))
        previous = street
    return passes


def test_the_route_passes_every_street_twice_each_way_and_again():
    """Three laps' worth of drive: every street of the 2 x 2 district passed at least twice (most four
    times), in both directions; a pass > 20 s after another one within a few metres, both ways."""
    scenario = CITY(duration_s=700.0, size=0.05)
    drive = scenario.drive
    time_s = np.arange(0.0, scenario.duration_s, 0.25)
    xyz, yaw = drive.pose_at_distance(drive.distance(time_s))
    passes = street_passes(xyz, yaw)
    assert len(passes) == 12  # 2 x 2 blocks: 3 lines of 2 streets along each axis
    assert all(len(p) >= 2 and {d for _, d in p} == {-1, 1} for p in passes.values())
    assert np.mean([len(p) >= 4 for p in passes.values()]) > 0.8

    # the same places again more than 20 s later, in the same and in the opposite direction
    sample = np.arange(0, len(time_s), 8)
    gap_m = np.linalg.norm(xyz[sample, None, :2] - xyz[None, sample, :2], axis=2)
    later = np.abs(time_s[sample, None] - time_s[None, sample]) > 20.0
    turned = np.abs((yaw[sample, None] - yaw[None, sample] + 180.0) % 360.0 - 180.0)
    revisit = (gap_m < 3.0) & later
    assert (revisit & (turned < 10.0)).any() and (revisit & (turned > 170.0)).any()

    speed = np.gradient(drive.distance(time_s), time_s)
    assert speed.max() > 8.0 and speed.min() < 0.1  # cruising, slowing, stopping
    turns = [seg.angle_deg for seg in drive.segments if seg.kind == "arc"]
    assert 90.0 in turns and -90.0 in turns


def test_a_short_drive_already_comes_back():
    """The default minute of drive passes some street twice, once each way."""
    scenario = CITY()
    time_s = np.arange(0.0, scenario.duration_s, 0.25)
    xyz, yaw = scenario.drive.pose_at_distance(scenario.drive.distance(time_s))
    assert any({d for _, d in p} == {-1, 1} for p in street_passes(xyz, yaw).values())


@pytest.mark.parametrize("blocks", [(2, 2), (3, 2), (2, 4), (4, 4)])
def test_street_circuit_takes_every_street_once_each_way_without_u_turn(blocks):
    circuit = street_circuit(*blocks, np.random.default_rng(5))
    steps = list(zip(circuit, circuit[1:] + circuit[:1]))
    n_x, n_y = blocks
    assert len(steps) == len(set(steps)) == 2 * (n_x * (n_y + 1) + n_y * (n_x + 1))
    assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1 for a, b in steps)
    after = steps[1:] + steps[:1]
    assert all(step[0] != following[1] for step, following in zip(steps, after))  # never straight back


def test_a_lap_with_a_turn_on_the_spot_is_refused():
    with pytest.raises(ConfigError, match="straights and arcs, not spin"):
        looped_drive(straight(50.0) + spin(90.0, 20.0), (0.0, 0.0), 0.0, 60.0, np.random.default_rng(0))


def test_drift_terms_are_seeded_and_of_their_stated_size():
    time_s = np.arange(0.0, 3000.0, 0.01)
    walk = ins_drift(time_s, InsErrors(position_walk_m_sqrt_s=0.005, heading_walk_deg_sqrt_s=0.002),
                     np.random.default_rng(1))
    per_second = np.diff(walk[0][::100], axis=0)
    assert per_second.std(axis=0) == pytest.approx([0.005] * 3, rel=0.05)
    assert np.diff(walk[1][::100]).std() == pytest.approx(0.002, rel=0.05)
    assert walk[0][0] == pytest.approx([0, 0, 0]) and walk[1][0] == 0

    slow = InsErrors(position_bias_m=0.02, bias_correlation_s=30.0)
    bias, heading = ins_drift(time_s, slow, np.random.default_rng(2))
    assert bias.std(axis=0) == pytest.approx([0.02] * 3, rel=0.2) and not heading.any()
    lag = 3000  # 30 s: one correlation time
    correlation = np.mean([np.corrcoef(bias[:-lag, k], bias[lag:, k])[0, 1] for k in range(3)])
    assert correlation == pytest.approx(np.exp(-1.0), abs=0.15)

    jumps, _ = ins_drift(time_s, InsErrors(jump_rate_hz=0.05, jump_m=0.03), np.random.default_rng(3))
    steps = np.diff(jumps, axis=0)
    jumped = np.any(steps != 0, axis=1)
    assert jumped.sum() == pytest.approx(0.05 * 3000, rel=0.25)
    assert steps[jumped].std() == pytest.approx(0.03, rel=0.15)

    again = ins_drift(time_s, InsErrors(jump_rate_hz=0.05, jump_m=0.03), np.random.default_rng(3))[0]
    other = ins_drift(time_s, InsErrors(jump_rate_hz=0.05, jump_m=0.03), np.random.default_rng(4))[0]
    np.testing.assert_array_equal(again, jumps)
    assert not np.array_equal(other, jumps)


def test_no_drift_draws_nothing():
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    position_m, heading_deg = ins_drift(np.arange(0.0, 10.0, 0.01), InsErrors(), rng)
    assert rng.bit_generator.state == state and not position_m.any() and not heading_deg.any()


def test_city_ins_drifts_a_few_cm_over_tens_of_seconds():
    """The recorded trajectory of city_loop departs from the truth by a few cm within 30 s, with jumps."""
    recording = simulate(CITY(duration_s=240.0, size=0.0005), quiet=True)
    ins, truth = recording.trajectory, recording.truth.trajectory
    error_m = ins.position - np.column_stack([np.interp(ins.time, truth.time, truth.position[:, k]) for k in range(3)])
    rate_hz = CITY().ins.rate_hz
    change_30s = np.linalg.norm(error_m[int(30 * rate_hz):] - error_m[:-int(30 * rate_hz)], axis=1)
    assert 0.02 < np.sqrt(np.mean(change_30s ** 2)) < 0.10
    step_m = np.linalg.norm(np.diff(error_m, axis=0), axis=1)
    assert (step_m > 0.02).sum() >= 3  # GNSS-like jumps (a walk step at 100 Hz is 0.5 mm)


@pytest.fixture(scope="module")
def stamped_city():
    """A few seconds of city_loop with stamps moved off the firing times (each laser stamped earlier by
    its id: returns come out of time order, across chunks too; a negative time offset), odometry and traffic."""
    base = CITY(duration_s=2.5, size=0.02, seed=3, traffic=True)
    return base.model_copy(update={"odometry": SEED_002_ODOMETRY, "effects": {
        "firing_delay": {"step_s": 2e-4}, "time_offset": {"offset_s": -0.03}}})


def test_streamed_recording_equals_the_in_memory_one(stamped_city, tmp_path):
    saved = simulate(stamped_city, quiet=True).save(tmp_path / "saved")
    streamed = simulate_to(stamped_city, tmp_path / "streamed", chunk_s=0.4, quiet=True)
    assert pq.ParquetFile(streamed / "points.parquet").metadata.num_row_groups >= 5
    assert pq.ParquetFile(streamed / "truth" / "points.parquet").metadata.num_row_groups >= 5
    a, b = Recording.load(saved), Recording.load(streamed)
    columns = a.points.read()
    assert len(columns["time"]) > 10_000 and (np.diff(columns["time"]) >= 0).all()
    for name, values in b.points.read().items():
        np.testing.assert_array_equal(values, columns[name], err_msg=name)
    np.testing.assert_array_equal(b.truth.world_points(), a.truth.world_points())
    np.testing.assert_array_equal(b.truth.moving(), a.truth.moving())
    assert a.truth.moving().mean() > 0.05  # the movers' returns cut into row groups as the static ones
    for name in ("recording.yaml", "sensor.yaml", "extrinsic.yaml", "trajectory.csv", "odometry.csv",
                 "truth/intrinsics.csv", "truth/extrinsic.yaml", "truth/trajectory.csv", "truth/effects.yaml"):
        assert filecmp.cmp(saved / name, streamed / name, shallow=False), name


def test_the_script_streams_a_recording_in_row_groups(tmp_path):
    out = tmp_path / "city"
    subprocess.run([sys.executable, str(SCENARIOS_DIR / "city_loop.py"), "--duration", "3.5", "--size", "0.02",
                    "--seed", "1", "--out", str(out), "--quiet", "--traffic", "--traffic-density", "0.5"], check=True)
    recording = Recording.load(out)
    assert recording.truth is not None and np.ptp(recording.trajectory.time) == pytest.approx(3.5)
    assert 0.02 < recording.truth.moving().mean() < 0.3  # half the default traffic
    assert pq.ParquetFile(out / "points.parquet").metadata.num_row_groups >= 3
