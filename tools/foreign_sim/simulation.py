"""Drive simulation: scene + vehicle + spinning head -> a recording directory (RECORDING.md).

Every random draw comes from numpy generators seeded from `seed` (one independent stream per
component, one per time chunk), so the scene, the drive, the sensor's true offsets and the
mounting do not change with `size` or the chunk length.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import time as _time
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation, Slerp

from tools.foreign_sim import mesh as M
from tools.foreign_sim import sensor as S
from tools.foreign_sim.departures import Departures
from tools.foreign_sim.drive import Suspension, drive_vehicle, recorded_ins
from tools.foreign_sim.scenes import FAMILIES, World, build_world
from tools.foreign_sim.writer import (FORMAT, POINT_SCHEMA, TRUTH_POINT_SCHEMA, RowGroupWriter, commit_output,
                                      prepare_output, write_intrinsics, write_trajectory, write_yaml)

CRS = "EPSG:32631"
TRUTH_RATE_HZ = 1000.0
MARGIN_S = 0.1  # the trajectories cover the returns by this much on both sides
# simulate's error bounds for the widest errors a factory model is expected to have: true offsets within 5 cm and
# 0.5 deg per fibre (range m, azimuth deg, elevation deg, height m), the extrinsic within 10 cm and 1 deg
WIDEST_FACTORY_ERRORS = {"intrinsic_bounds": (0.05, 0.5, 0.5, 0.05), "extrinsic_lever_m": 0.10,
                         "extrinsic_angle_deg": 1.0}
_STREAMS = ("scene", "drive", "mount", "intrinsics", "spin", "ins", "frame")


def _rpy_rotation(rpy_deg) -> Rotation:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from roll, pitch, yaw [deg] (intrinsic z-y'-x'')."""
    rpy = np.asarray(rpy_deg, dtype=np.float64)
    return Rotation.from_euler("ZYX", rpy[..., ::-1], degrees=True)


def _rpy_of(rotation: Rotation) -> np.ndarray:
    return rotation.as_euler("ZYX", degrees=True)[..., ::-1]


def draw_mounting(rng, mount: str, lever_error_m: float, angle_error_deg: float) -> dict:
    """Nominal (extrinsic.yaml) and true lidar -> body pose.

    level: boresight (0, 0, yaw0), yaw0 in {0, 90, -90}. tilted: the head is in addition pitched
    forward (about the body's y axis) or rolled sideways (about its x axis) by 10-25 deg."""
    yaw0 = float(rng.choice([0.0, 90.0, -90.0]))
    lever = np.array([round(float(rng.uniform(0.6, 1.2)), 2), 0.0, round(float(rng.uniform(1.8, 2.0)), 2)])
    tilt = {"axis": "none", "deg": 0.0}
    if mount == "level":
        nominal_rpy = np.array([0.0, 0.0, yaw0])
    elif mount == "tilted":
        angle = round(float(rng.uniform(10.0, 25.0)), 1)
        if rng.random() < 0.5:
            tilt = {"axis": "pitch, nose down (body y)", "deg": angle}
            body_tilt = Rotation.from_euler("y", angle, degrees=True)
        else:
            angle *= float(rng.choice([-1.0, 1.0]))
            tilt = {"axis": "roll (body x)", "deg": angle}
            body_tilt = Rotation.from_euler("x", angle, degrees=True)
        nominal_rpy = np.round(_rpy_of(body_tilt * Rotation.from_euler("z", yaw0, degrees=True)), 6)
    else:
        raise ValueError(f"mount must be 'level' or 'tilted', not {mount!r}")
    true_lever = lever + rng.uniform(-lever_error_m, lever_error_m, 3)
    true_rpy = nominal_rpy + rng.uniform(-angle_error_deg, angle_error_deg, 3)
    return {"nominal": {"lever_arm_m": lever.tolist(), "boresight_deg": [float(v) for v in nominal_rpy]},
            "true": {"lever_arm_m": [float(v) for v in true_lever], "boresight_deg": [float(v) for v in true_rpy]},
            "yaw0_deg": yaw0, "tilt": tilt}


class _Raycaster:
    """open3d's RaycastingScene (float32) with each hit refined on its triangle's plane in float64."""

    def __init__(self, mesh: M.Mesh):
        self.mesh = mesh
        self.normals = mesh.normals()
        self.p0 = mesh.vertices[mesh.triangles[:, 0]]
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                                 o3d.core.Tensor(mesh.triangles.astype(np.uint32)))

    def cast(self, origin: np.ndarray, direction: np.ndarray):
        rays = np.hstack([origin, direction]).astype(np.float32)
        answer = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = answer["t_hit"].numpy().astype(np.float64)
        prim = answer["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        idx = np.flatnonzero(hit)
        p = prim[idx]
        n = self.normals[p]
        denom = np.einsum("ij,ij->i", n, direction[idx])
        num = np.einsum("ij,ij->i", n, self.p0[p] - origin[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            refined = num / denom
        good = (np.abs(denom) > 0.02) & (np.abs(refined - t[idx]) < 0.05)
        t[idx] = np.where(good, refined, t[idx])
        return hit, t, np.where(hit, prim, -1), np.abs(denom)


def scans(reading_rad: np.ndarray, last_scan: float = -np.inf) -> np.ndarray:
    """The scan (revolution count) of each return, in firing order, from the encoder's unwrapped readings [rad]:
    a scan is cut where the reading first wraps, as a driver cuts it, so that a firing read just behind the cut
    (the encoder's jitter) stays in the new scan; last_scan: the scan the previous returns ended in."""
    return np.maximum.accumulate(np.r_[last_scan, np.floor(reading_rad / (2 * np.pi))])[1:]


def simulate(family: str, out, *, duration_s: float = 15.0, size: float = 1.0, seed: int = 0,
             mount: str = "level", range_noise_m: float = 0.01, intrinsic_bounds=(0.03, 0.3, 0.3, 0.03),
             extrinsic_lever_m: float = 0.05, extrinsic_angle_deg: float = 0.5, ins_noise_m: float = 0.005,
             ins_noise_deg: float = 0.005, ins_drift_m: float = 0.0, ins_drift_deg: float = 0.0,
             ins_rate_hz: float = 200.0, encoder_jitter_deg: float = 0.002, spin_wander_rpm: float = 0.5,
             departures: Departures = Departures(), chunk_s: float = 0.5, name: str | None = None,
             verbose: bool = False) -> Path:
    """Simulate a drive through a scene of `family` and write its recording directory `out`.

    size: fraction of the firing blocks kept (each block of 32 lasers kept with that probability).
    intrinsic_bounds: (d_range m, d_azimuth deg, d_elevation deg, h_z m), true offsets uniform
    within +-bounds. departures: the physics beyond the contract's model switched on (departures.py);
    returns whose stamp falls outside the recorded INS are not written. Returns the recording directory."""
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; known: {', '.join(FAMILIES)}")
    if not 0.0 < size <= 1.0:
        raise ValueError(f"size must be in (0, 1], not {size}")
    if not duration_s > 0:
        raise ValueError(f"duration_s must be positive, not {duration_s}")
    if TRUTH_RATE_HZ % ins_rate_hz:
        raise ValueError(f"ins_rate_hz must divide {TRUTH_RATE_HZ:g} Hz")
    if abs(departures.latency_s) > MARGIN_S / 2:
        raise ValueError(f"latency_s must be within +-{MARGIN_S / 2:g} s, not {departures.latency_s}")
    out = Path(out)
    started = _time.perf_counter()

    def say(message: str) -> None:
        if verbose:
            print(f"[foreign_sim {_time.perf_counter() - started:6.1f} s] {message}", file=sys.stderr, flush=True)

    streams = dict(zip(_STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(len(_STREAMS)))))
    world: World = build_world(family, streams["scene"], duration_s)
    say(f"{family}: {len(world.mesh.triangles):,} triangles, {world.notes}")

    # --- the frame: where the layout sits in the projected CRS, and the clock -------------------
    rf = streams["frame"]
    origin = np.array([500000.0 + rf.uniform(-3000, 3000), 4500000.0 + rf.uniform(-3000, 3000),
                       30.0 + rf.uniform(0, 60)])
    origin = np.round(origin, 3)
    heading0 = float(rf.uniform(-180.0, 180.0))  # the layout's +x in grid axes [deg, ccw from east]
    t0 = round(345600.0 + float(rf.uniform(0.0, 3600.0)), 3)  # GPS seconds of week of the first firing
    R_grid = Rotation.from_euler("z", heading0, degrees=True)

    # --- the vehicle: truth at 1 kHz, INS from it -----------------------------------------------
    rd = streams["drive"]
    suspension = Suspension(pitch_per_accel_deg=float(rd.uniform(0.5, 1.0)),
                            roll_per_accel_deg=float(rd.uniform(0.5, 1.0)))
    n_margin = int(round(MARGIN_S * TRUTH_RATE_HZ))
    steps = np.arange(-n_margin, int(np.ceil(duration_s * TRUTH_RATE_HZ)) + n_margin + 1)
    t_rel = steps / TRUTH_RATE_HZ
    truth = drive_vehicle(world.path, world.speed, world.ground_z, t_rel, suspension, rd, TRUTH_RATE_HZ)
    key_time = t0 + t_rel
    key_rotation = _rpy_rotation(truth.rpy_deg)
    slerp = Slerp(key_time, key_rotation)
    world_position = origin + R_grid.apply(truth.position)
    world_rpy = truth.rpy_deg + np.array([0.0, 0.0, heading0])
    every = int(TRUTH_RATE_HZ / ins_rate_hz)
    ins_rows = np.flatnonzero(steps % every == 0)
    ins_time = key_time[ins_rows]
    ins_position, ins_rpy = recorded_ins(ins_time, world_position[ins_rows], world_rpy[ins_rows],
                                         streams["ins"], ins_noise_m, ins_noise_deg, ins_drift_m, ins_drift_deg)
    ins_rpy[:, 2] = departures.ins_yaw_deg(ins_time, ins_rpy[:, 2])
    say(f"drive: {truth.speed.min():.1f}-{truth.speed.max():.1f} m/s, |yaw rate| <= "
        f"{np.abs(truth.yaw_rate_deg).max():.1f} deg/s, "
        f"roll {truth.rpy_deg[:, 0].min():+.2f}..{truth.rpy_deg[:, 0].max():+.2f}, "
        f"pitch {truth.rpy_deg[:, 1].min():+.2f}..{truth.rpy_deg[:, 1].max():+.2f} deg")

    # --- the sensor --------------------------------------------------------------------------------
    mounting = draw_mounting(streams["mount"], mount, extrinsic_lever_m, extrinsic_angle_deg)
    R_bl = _rpy_rotation(mounting["true"]["boresight_deg"]).as_matrix()
    T_bl = np.asarray(mounting["true"]["lever_arm_m"])
    offsets = S.draw_intrinsics(streams["intrinsics"], intrinsic_bounds)
    rs = streams["spin"]
    spin = S.HeadSpin.draw(0.0, rs, spin_wander_rpm)
    n_revolutions = int(np.ceil(duration_s * S.ROTATION_HZ * 1.01)) + 3
    jitter = np.radians(encoder_jitter_deg) * rs.standard_normal(n_revolutions)
    caster = _Raycaster(world.mesh)
    retro = world.mesh.material == M.SIGN
    glass = world.mesh.material == M.GLASS
    ground = world.mesh.material == M.GROUND

    tmp = prepare_output(out)
    points = RowGroupWriter(tmp / "points.parquet", POINT_SCHEMA)
    truth_points = RowGroupWriter(tmp / "truth" / "points.parquet", TRUTH_POINT_SCHEMA)
    n_blocks = int(np.floor(duration_s / S.BLOCK_PERIOD_S)) + 1
    per_chunk = max(1, int(round(chunk_s / S.BLOCK_PERIOD_S)))
    lasers = np.arange(S.N_FIBRES)
    stats = {"firings": 0, "hits": 0, "returns": 0}
    last_scan = -np.inf
    try:
        for chunk, k0 in enumerate(range(0, n_blocks, per_chunk)):
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xB10C, chunk)))
            blocks = np.arange(k0, min(k0 + per_chunk, n_blocks))
            if size < 1.0:
                blocks = blocks[rng.random(len(blocks)) < size]
            if len(blocks) == 0:
                continue
            fire = (blocks[:, None] * S.BLOCK_PERIOD_S + lasers * S.LASER_SPACING_S).ravel()  # drive clock
            fibre = np.tile(lasers, len(blocks))
            t_abs = t0 + fire
            psi = spin.angle(fire)
            # the body pose at each laser's own firing time
            index = np.clip(np.searchsorted(key_time, t_abs, side="right") - 1, 0, len(key_time) - 2)
            alpha = ((t_abs - key_time[index]) / (key_time[index + 1] - key_time[index]))[:, None]
            position = (1 - alpha) * truth.position[index] + alpha * truth.position[index + 1]
            rotation = slerp(t_abs)
            d_lidar = S.beam_directions(psi, fibre, offsets)
            o_body = T_bl + np.column_stack([np.zeros((len(fibre), 2)), offsets[fibre, 3]]) @ R_bl.T
            origin_l = rotation.apply(o_body) + position
            direction = rotation.apply(d_lidar @ R_bl.T)
            hit, dist, prim, cos_inc = caster.cast(origin_l, direction)
            idx = np.flatnonzero(hit)
            p = prim[idx]
            d = dist[idx]
            point = origin_l[idx] + d[:, None] * direction[idx]
            refl = world.mesh.reflectivity[p].copy()
            on_ground = ground[p]
            if on_ground.any():
                refl[on_ground] = world.texture(point[on_ground])
            strength = S.detection_strength(refl, cos_inc, d, retro[p])
            strength = np.where(glass[p], 0.25 * strength, strength)
            detected = rng.random(len(idx)) < 1.0 - np.exp(-strength / 0.012)
            rho = (departures.measured_distance(d, cos_inc) - offsets[fibre[idx], 0]
                   + range_noise_m * rng.standard_normal(len(idx)))
            rev = np.floor(psi[idx] / (2 * np.pi)).astype(np.int64)
            recorded = departures.encoder_reading(psi[idx]) + jitter[np.clip(rev, 0, n_revolutions - 1)]
            scan = scans(recorded, last_scan)
            last_scan = scan[-1] if len(scan) else last_scan
            cuts, which = np.unique(scan, return_inverse=True)
            stamp = departures.stamp(t_abs[idx], t0 + spin.time_at(2 * np.pi * cuts)[which])
            keep = (detected & (rho >= S.MIN_RANGE_M) & (rho <= S.MAX_RANGE_M)
                    & (stamp >= ins_time[0]) & (stamp <= ins_time[-1]))
            rows = idx[keep]
            scan, recorded = scan[keep], recorded[keep]
            azimuth = np.mod(recorded, 2 * np.pi)
            intensity = 255.0 * np.minimum(1.6 * strength[keep], 1.0) * (1.0 + 0.05 * rng.standard_normal(len(rows)))
            intensity = np.clip(np.round(intensity + rng.normal(0.0, 1.0, len(rows))), 0.0, 255.0)
            points.append({"time": stamp[keep], "fibre": fibre[rows].astype(np.int16),
                           "range": rho[keep].astype(np.float32), "azimuth": azimuth.astype(np.float32),
                           "intensity": intensity.astype(np.float32), "scan": scan.astype(np.int32)})
            xyz = origin + R_grid.apply(point[keep])
            truth_points.append({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]})
            stats["firings"] += len(fibre)
            stats["hits"] += len(idx)
            stats["returns"] += len(rows)
            say(f"chunk {chunk}: t {fire[0]:.2f}-{fire[-1]:.2f} s, {len(fibre):,} firings, {len(rows):,} returns")
        points.close()
        truth_points.close()
        if stats["returns"] == 0:
            raise RuntimeError("no return at all: is the duration or the size too small?")

        # --- the other files -------------------------------------------------------------------------
        name = name or f"foreign-{family}-s{seed}"
        notes = [f"tools.foreign_sim family {family}, seed {seed}, size {size:g}, {duration_s:g} s, mount {mount}",
                 "simulated independently of graphcal: own scene, dynamics, firing and raycasting"]
        write_yaml(tmp / "recording.yaml", {"format": FORMAT, "name": name, "crs": CRS,
                                            "source": {"simulator": "tools.foreign_sim", "family": family,
                                                       "seed": int(seed), "notes": notes}})
        write_yaml(tmp / "sensor.yaml", {"model": S.MODEL, "rotation_hz": S.ROTATION_HZ,
                                         "reference_fibre": S.REFERENCE_FIBRE,
                                         "fibres": [{"id": i, "elevation_deg": float(e)}
                                                    for i, e in enumerate(S.ELEVATION_DEG)]})
        write_yaml(tmp / "extrinsic.yaml", mounting["nominal"])
        write_trajectory(tmp / "trajectory.csv", ins_time, ins_position, ins_rpy)
        write_intrinsics(tmp / "truth" / "intrinsics.csv", offsets)
        write_yaml(tmp / "truth" / "extrinsic.yaml", mounting["true"])
        write_trajectory(tmp / "truth" / "trajectory.csv", key_time, world_position, world_rpy)
        write_yaml(tmp / "truth" / "effects.yaml", _effects(encoder_jitter_deg, ins_drift_m, ins_drift_deg, departures))
        np.savez_compressed(tmp / "truth" / "scene.npz", vertices=world.mesh.vertices, triangles=world.mesh.triangles,
                            reflectivity=world.mesh.reflectivity, material=world.mesh.material,
                            origin=origin, heading_deg=np.array(heading0))
        rpm_seen = spin.rpm(np.linspace(0.0, duration_s, 2000))
        settings = {"family": family, "seed": int(seed), "duration_s": float(duration_s), "size": float(size),
                    "mount": mount, "range_noise_m": float(range_noise_m),
                    "intrinsic_bounds": dict(zip(("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m"),
                                                 map(float, intrinsic_bounds))),
                    "extrinsic_lever_m": float(extrinsic_lever_m), "extrinsic_angle_deg": float(extrinsic_angle_deg),
                    "ins": {"rate_hz": float(ins_rate_hz), "noise_m": float(ins_noise_m),
                            "noise_deg": float(ins_noise_deg), "drift_m": float(ins_drift_m),
                            "drift_deg": float(ins_drift_deg)},
                    "departures": departures.settings(),
                    "truth_rate_hz": TRUTH_RATE_HZ, "first_firing_time_s": t0,
                    "layout_to_grid": {"origin_m": origin.tolist(), "heading_deg": heading0,
                                       "meaning": "grid = origin + Rz(heading) layout (truth/scene.npz is in layout)"},
                    "mounting": {"yaw0_deg": mounting["yaw0_deg"], "tilt": mounting["tilt"]},
                    "spin": {"nominal_rpm": 600.0, "wander_rpm": float(spin_wander_rpm),
                             "rpm_range_seen": [float(rpm_seen.min()), float(rpm_seen.max())]},
                    "firing": {"block_period_us": S.BLOCK_PERIOD_S * 1e6, "laser_spacing_us": S.LASER_SPACING_S * 1e6,
                               "blocks_kept": "each block with probability size"},
                    "suspension": {"pitch_per_accel_deg": suspension.pitch_per_accel_deg,
                                   "roll_per_accel_deg": suspension.roll_per_accel_deg},
                    "drive": {"speed_m_s": [float(truth.speed.min()), float(truth.speed.max())],
                              "max_yaw_rate_deg_s": float(np.abs(truth.yaw_rate_deg).max()),
                              "max_accel_long_m_s2": float(np.abs(truth.accel_long).max()),
                              "max_accel_lat_m_s2": float(np.abs(truth.accel_lat).max())},
                    "scene": {"triangles": int(len(world.mesh.triangles)), **_plain(world.notes)},
                    "counts": stats, "wall_time_s": round(_time.perf_counter() - started, 2)}
        write_yaml(tmp / "truth" / "simulator.yaml", settings)
    except BaseException:
        for writer in (points, truth_points):
            with contextlib.suppress(Exception):
                writer.writer.close()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    path = commit_output(tmp, out)
    say(f"{stats['returns']:,} returns of {stats['firings']:,} firings written to {path}")
    return path


def _plain(value):
    """numpy scalars and tuples -> plain YAML-safe Python."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _effects(encoder_jitter_deg: float, ins_drift_m: float, ins_drift_deg: float, departures: Departures) -> dict:
    """truth/effects.yaml: the physics on top of the contract's model, with magnitudes."""
    if departures.revolution_stamps:
        sweep = {"stamp": "revolution", "magnitude": 1.0, "unit": "revolution",
                 "physics": "the vehicle moves while the head spins; every return is taken from the pose at its "
                            "laser's firing time but stamped with its revolution's start"}
    else:
        sweep = {"stamp": "firing", "magnitude": 0.0, "unit": "revolution",
                 "physics": "the vehicle moves while the head spins; every return carries its own laser's firing "
                            "time and is taken from the pose at it"}
    effects = {"intra_sweep_motion": sweep, **departures.effects()}
    if encoder_jitter_deg > 0:
        effects["encoder_jitter"] = {"rms_deg": float(encoder_jitter_deg), "magnitude": float(encoder_jitter_deg),
                                     "unit": "deg", "physics": "the recorded encoder azimuth is off the head's true "
                                     "angle by a random constant per revolution (Gaussian, this RMS)"}
    if ins_drift_m > 0:
        effects["ins_position_drift"] = {"peak_m": float(ins_drift_m), "magnitude": float(ins_drift_m), "unit": "m",
                                         "physics": "the recorded INS position wanders slowly (periods 40-200 s) "
                                                    "away from the truth"}
    if ins_drift_deg > 0:
        effects["ins_attitude_drift"] = {"peak_deg": float(ins_drift_deg), "magnitude": float(ins_drift_deg),
                                         "unit": "deg", "physics": "the recorded INS attitude (mostly heading) "
                                                                    "wanders slowly away from the truth"}
    return effects
