"""graphcal.simulate(scenario) -> Recording: raycast a spinning multi-beam lidar on a moving vehicle.

For every firing: its own time -> true pose (PoseTrack of the truth) -> true beam (eq. 4.2
with the true offsets, true extrinsic) -> open3d raycast -> the raw values a real sensor
reports (inverse of eq. 4.2 with the true offsets, encoder azimuth, noise, effects).

The returns are cast chunk by chunk and put in time order as they come (_returns): simulate keeps
them all in memory; simulate_to writes each chunk_s seconds of them as a row group of points.parquet
and truth/points.parquet, so that its memory stays flat whatever the duration (only the trajectories
and odometry, a few kB per second of drive, are held whole).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pyproj import CRS

from factors.spherical import FactoryTerms, beam_rays, from_xyz
from factors.effects import Effect
from graphcal.common.atomic import atomic_directory
from graphcal.simulation.effects import build_effects, describe
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.points import SCHEMA, PointTable, point_schema, row_group_writer
from graphcal.recording.poses import PoseTrack
from graphcal.common.progress import progress
from graphcal.recording.directory import Recording
from graphcal.recording.sensor import SensorModel, sensor_from_catalog
from graphcal.simulation.ins import recorded_poses, to_trajectory, true_poses
from graphcal.simulation.odometry import simulate_odometry
from graphcal.simulation.scenario import Scenario, draw_offsets
from graphcal.simulation.scene import RaycastScene
from graphcal.simulation.traffic import Mover, cast_movers
from graphcal.recording.truth import WORLD_POINTS, Truth, world_point_writer

# the lidar records inside the trajectory span, this far from each end [s]
_EDGE_S = 0.1
# seconds of firings per row group of simulate_to (and per batch of simulate)
CHUNK_S = 1.0


@dataclass(frozen=True)
class _Rig:
    """The true state the rays are cast from."""

    sensor: SensorModel
    offsets: np.ndarray  # (n_fibres, 4) true offsets, m rad rad m
    extrinsic: Extrinsic
    poses: PoseTrack  # true T_local_body
    effects: list[Effect]
    noise_m: float
    min_range_m: float
    max_range_m: float

    @property
    def spin_hz(self) -> float:
        """The head's true spin rate [Hz] as the effects make it."""
        spin_hz = self.sensor.rotation_hz
        for effect in self.effects:
            spin_hz = effect.spin_hz(spin_hz)
        return spin_hz


def simulate(scenario: Scenario, quiet: bool = False) -> Recording:
    """Simulate a recording (with truth/) from a scenario, in memory. Deterministic for a given seed."""
    rig, nominal, rng = _prepare(scenario)
    batches = list(_returns(scenario, rig, rng, CHUNK_S, quiet))
    columns = {name: np.concatenate([batch[name] for batch, _, _ in batches]) for name in batches[0][0]}
    world = np.concatenate([xyz for _, xyz, _ in batches])
    moving = np.concatenate([flag for _, _, flag in batches]) if scenario.traffic is not None else None
    return _recording(scenario, rig, nominal, rng, PointTable.from_arrays(**columns), world, moving)


def simulate_to(scenario: Scenario, directory: str | Path, chunk_s: float = CHUNK_S, quiet: bool = False) -> Path:
    """Simulate a recording straight into `directory` (replaced whole, atomically), points.parquet and
    truth/points.parquet one row group per chunk_s seconds of firings [s], so that memory does not grow
    with the duration. The folder holds what simulate(scenario).save(directory) writes, row for row."""
    rig, nominal, rng = _prepare(scenario)
    directory = Path(directory)
    with atomic_directory(directory) as tmp:
        (tmp / "truth").mkdir()
        with (row_group_writer(tmp / "points.parquet", point_schema(list(SCHEMA))) as write_points,
              world_point_writer(tmp / "truth" / WORLD_POINTS, moving=scenario.traffic is not None) as write_world):
            for columns, world, moving in _returns(scenario, rig, rng, chunk_s, quiet):
                write_points(columns)
                write_world(world, moving)
        _recording(scenario, rig, nominal, rng, PointTable.open(tmp / "points.parquet")).save_beside_points(tmp)
    return directory


def _prepare(scenario: Scenario) -> tuple[_Rig, Extrinsic, np.random.Generator]:
    """The true rig, the nominal extrinsic and the generator every later draw takes from (offsets drawn)."""
    rng = np.random.default_rng(scenario.seed)
    sensor = sensor_from_catalog(scenario.sensor_model, scenario.rotation_hz)
    spec = scenario.extrinsic
    nominal = Extrinsic(spec.lever_arm_m, spec.boresight_deg)
    true_extrinsic = Extrinsic(tuple(np.add(spec.lever_arm_m, spec.error_lever_arm_m)),
                               tuple(np.add(spec.boresight_deg, spec.error_boresight_deg)))
    offsets = draw_offsets(scenario.intrinsic_errors, sensor.n_fibres, sensor.reference_fibre, rng)
    truth_poses = true_poses(scenario.drive, scenario.start_time_s, scenario.duration_s, scenario.truth_rate_hz)
    rig = _Rig(sensor, offsets, true_extrinsic, truth_poses, build_effects(scenario.effects), scenario.range_noise_m,
               scenario.min_range_m, scenario.max_range_m)
    return rig, nominal, rng


def _recording(scenario: Scenario, rig: _Rig, nominal: Extrinsic, rng: np.random.Generator, points: PointTable,
               world_points: np.ndarray | None = None, moving: np.ndarray | None = None) -> Recording:
    """The recording around the cast returns: INS and odometry drawn (after the returns), truth (with the
    true world points [m, grid frame] and which returns are on moving traffic, when given)."""
    crs = CRS.from_user_input(scenario.crs)
    geodetic = scenario.trajectory_format == "geodetic"
    ins = recorded_poses(rig.poses, scenario.ins, rig.effects, rng)
    odometry = (None if scenario.odometry is None else
                simulate_odometry(scenario.drive, scenario.odometry, scenario.start_time_s, scenario.duration_s, rng))
    truth = Truth(intrinsics=rig.offsets, extrinsic=rig.extrinsic,
                  trajectory=to_trajectory(rig.poses, scenario.origin_m, crs, geodetic),
                  effects=describe(rig.effects), _world_points=world_points, _moving=moving)
    return Recording(name=scenario.name, crs=scenario.crs, sensor=rig.sensor, extrinsic=nominal,
                     trajectory=to_trajectory(ins, scenario.origin_m, crs, geodetic),
                     points=points, odometry=odometry, _truth=truth)


def firing_times(scenario: Scenario, sensor: SensorModel, effects: list[Effect]) -> tuple[np.ndarray, float]:
    """Start time of every kept firing cycle [s] (every 1/size-th cycle) and the lidar start.
    The lidar keeps clear of the trajectory's ends so that every stamped time is inside it."""
    timing = sensor.timing
    stride = max(int(round(1.0 / scenario.size)), 1)
    margin = _EDGE_S + sum(effect.max_stamp_shift_s() for effect in effects)
    lidar_start = scenario.start_time_s + margin
    lidar_end = scenario.start_time_s + scenario.duration_s - margin
    n_cycles = int((lidar_end - lidar_start) / timing.cycle_s)
    return lidar_start + np.arange(0, n_cycles, stride) * timing.cycle_s, lidar_start


def _returns(scenario: Scenario, rig: _Rig, rng: np.random.Generator, chunk_s: float,
             quiet: bool) -> Iterator[tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]]:
    """The returns in time order, a batch per chunk_s [s] of firings: (raw columns, true world xyz [m, grid frame],
    on a mover of the traffic (bool)).

    Rays are cast in chunks of 0.25 s (0.01 s when objects move: the scene is rebuilt for each), the same
    whatever chunk_s, so that the returns do not depend on it. Returns whose stamp a later firing may still
    precede (stamps lag the firing by up to a revolution plus the effects' max_stamp_shift_s) wait for the
    next batch; concatenated, the batches are every return in a stable sort by time.
    """
    scene = _Scene(RaycastScene(scenario.scene), movers(scenario))
    cycles, lidar_start = firing_times(scenario, rig.sensor, rig.effects)
    casts = _chunks(cycles, 0.01 if scene.static.moving else 0.25)
    lag_s = 1.0 / rig.spin_hz + sum(effect.max_stamp_shift_s() for effect in rig.effects)
    batches = [list(group) for _, group in
               itertools.groupby(casts, key=lambda c: int((cycles[c.start] - cycles[0]) // chunk_s))]
    origin_m = np.asarray(scenario.origin_m)
    waiting = []
    for batch in progress(batches, f"simulating {scenario.name}", total=len(batches), quiet=quiet):
        parts = waiting + [_cast_chunk(cycles[c], lidar_start, scenario, rig, scene, rng) for c in batch]
        columns = {name: np.concatenate([p[0][name] for p in parts]) for name in parts[0][0]}
        world = np.concatenate([p[1] for p in parts])
        moving = np.concatenate([p[2] for p in parts])
        order = np.argsort(columns["time"], kind="stable")
        columns, world, moving = {name: values[order] for name, values in columns.items()}, world[order], moving[order]
        next_firing_s = cycles[batch[-1].stop] if batch[-1].stop < len(cycles) else np.inf
        ready = int(np.searchsorted(columns["time"], next_firing_s - lag_s))
        yield {name: values[:ready] for name, values in columns.items()}, world[:ready] + origin_m, moving[:ready]
        waiting = [({name: values[ready:] for name, values in columns.items()}, world[ready:], moving[ready:])]


def _chunks(cycles: np.ndarray, chunk_s: float) -> list[slice]:
    """Consecutive non-empty slices of the firing cycles' start times [s], chunk_s apart."""
    edges = np.searchsorted(cycles, np.arange(cycles[0], cycles[-1] + chunk_s, chunk_s))
    return [slice(a, b) for a, b in zip(edges, np.r_[edges[1:], len(cycles)]) if b > a]


@dataclass(frozen=True)
class _Scene:
    """What the rays hit: the static scene (open3d; its own constant-velocity clutter cast at a chunk's mean
    time) and the traffic's movers (each at every ray's own time)."""

    static: RaycastScene
    movers: list[Mover]

    def __post_init__(self):
        # (M, 2) each mover's existence [s from the start], to cast a chunk against those that exist then only
        object.__setattr__(self, "spans", np.array([m.span for m in self.movers], dtype=np.float64).reshape(-1, 2))

    @property
    def reflectivity(self) -> np.ndarray:
        """Of the static objects, then of the movers (the indices cast returns)."""
        return np.r_[self.static.reflectivity, [m.reflectivity for m in self.movers]].astype(np.float32)

    def cast(self, origins: np.ndarray, directions: np.ndarray, elapsed_s: np.ndarray, max_range_m: float):
        """Rays [m, local frame] fired at elapsed_s (N,) [s from the start] -> (distance m, inf on a miss;
        object index, the movers after the static objects; unit normal; on a mover (bool))."""
        distance, index, normal = self.static.cast(origins, directions, float(np.mean(elapsed_s)))
        active = np.flatnonzero((self.spans[:, 0] <= elapsed_s.max()) & (self.spans[:, 1] >= elapsed_s.min()))
        moved_distance, mover, moved_normal = cast_movers([self.movers[k] for k in active], origins, directions,
                                                          elapsed_s, np.minimum(distance, max_range_m))
        mover = np.where(mover >= 0, active[np.maximum(mover, 0)] if len(active) else 0, -1)
        on_mover = moved_distance < distance
        distance = np.where(on_mover, moved_distance, distance)
        index = np.where(on_mover, len(self.static.objects) + mover, index)
        normal = np.where(on_mover[:, None], moved_normal, normal)
        return distance, index, normal, on_mover


def movers(scenario: Scenario) -> list[Mover]:
    """The traffic's movers for the scenario's drive (none without traffic)."""
    if scenario.traffic is None:
        return []
    return scenario.traffic.movers(scenario.drive.pose_at, scenario.duration_s)


def _cast_chunk(cycle_start, lidar_start, scenario, rig: _Rig, scene: _Scene, rng):
    sensor, n = rig.sensor, rig.sensor.n_fibres
    fibre = np.tile(np.arange(n, dtype=np.int16), len(cycle_start))
    t_fire = (cycle_start[:, None] + sensor.timing.laser_spacing_s * np.arange(n)[None, :]).ravel()
    spin_hz = rig.spin_hz
    turns = spin_hz * (t_fire - lidar_start)
    revolution = np.floor(turns)
    t_rev = lidar_start + revolution / spin_hz
    encoder = 2 * np.pi * (turns - revolution)

    t_pose, beam_azimuth, elevation_change = t_rev, encoder, np.zeros(len(encoder))
    for effect in rig.effects:
        t_pose = effect.pose_time(t_pose, t_fire, t_rev)
        beam_azimuth = effect.beam_azimuth(beam_azimuth)
        elevation_change = elevation_change + effect.beam_elevation(encoder)
    factory = _true_factory_terms(sensor, fibre, rig.effects, elevation_change)
    origin_lidar, direction_lidar = beam_rays(beam_azimuth, factory, rig.offsets[fibre])
    position, rotation = rig.poses.interpolate(t_pose)
    origin = rotation.apply(rig.extrinsic.lidar_to_body(origin_lidar)) + position
    direction = rotation.apply(direction_lidar @ rig.extrinsic.R_body_lidar.T)
    distance, hit_object, normal, on_mover = scene.cast(origin, direction, t_fire - scenario.start_time_s,
                                                       rig.max_range_m)

    hit = np.isfinite(distance) & (distance >= rig.min_range_m) & (distance <= rig.max_range_m)
    fibre, encoder, t_fire, t_rev = fibre[hit], encoder[hit], t_fire[hit], t_rev[hit]
    # the raw range a perfect sensor reports, by the inverse of eq. 4.2 with the true offsets
    p_lidar = origin_lidar[hit] + distance[hit, None] * direction_lidar[hit]
    ideal_range, _, _ = from_xyz(p_lidar, _true_factory_terms(sensor, fibre, rig.effects, elevation_change[hit]),
                                 rig.offsets[fibre])
    cos_incidence = np.abs(np.sum(normal[hit] * direction[hit], axis=1))
    world = origin[hit] + distance[hit, None] * direction[hit]
    reflectivity = scene.reflectivity[hit_object[hit]]
    if scenario.markings is not None:  # painted on the static surfaces, not on the traffic
        reflectivity = np.where(on_mover[hit], reflectivity, reflectivity * scenario.markings.factor(world))
    intensity = np.clip(255.0 * reflectivity * cos_incidence, 0, 255)
    range_m, t_rec = ideal_range, t_fire
    for effect in rig.effects:
        range_m = effect.measured_range(range_m, cos_incidence, intensity, t_fire - scenario.start_time_s)
        t_rec = effect.recorded_time(t_rec, t_fire, t_rev, fibre)
    range_m = range_m + rng.normal(0.0, rig.noise_m, len(range_m)) if rig.noise_m > 0 else range_m
    columns = {"time": t_rec, "fibre": fibre, "range": range_m, "azimuth": encoder, "intensity": intensity,
               "scan": revolution[hit].astype(np.int32)}
    return columns, world, on_mover[hit]


def _true_factory_terms(sensor: SensorModel, fibre: np.ndarray, effects: list[Effect],
                        elevation_change_rad: np.ndarray) -> FactoryTerms:
    """The factory terms of the returns' fibres as the effects make them (nominal by default), each beam's
    elevation changed by elevation_change_rad (the effects' beam_elevation at its encoder reading)."""
    factory = sensor.factory_terms(fibre)
    for effect in effects:
        factory = effect.factory_terms(factory, fibre)
    return replace(factory, elevation_rad=factory.elevation_rad + elevation_change_rad)
