"""Georeferencing of the trajectory with pyproj: WGS84 -> projected world frame (UTM by default).

The world frame is the projected CRS: x east (grid), y north (grid), z ellipsoidal height [m].
Geodetic attitudes are relative to local East-North-Up; the grid axes are turned from ENU by
the meridian convergence gamma, so R_grid_body = Rz(gamma) R_enu_body and grid yaw = yaw + gamma
(pyproj's `meridian_convergence` is exactly that angle, counter-clockwise positive).
The grid scale factor k (grid length / true length) is kept for later stages; it is not
applied to the lidar points here.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from pyproj import CRS, Proj, Transformer
from pyproj.aoi import AreaOfInterest
from pyproj.database import query_utm_crs_info
from pyproj.exceptions import CRSError
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.recording.poses import PoseTrack
from graphcal.recording.rotations import rotation_from_rpy_deg
from graphcal.recording.trajectory import Trajectory
from graphcal.recording.trajectory_noise import PoseNoise, smoothed_poses

WGS84_3D = "EPSG:4979"


@dataclass(frozen=True)
class WorldTrajectory:
    """T_world_body(t) in the projected CRS, with the map factors at each fix.

    poses: body -> world; scale_factor: grid scale k at each fix (dimensionless);
    convergence_deg: meridian convergence gamma at each fix [deg]; measured_noise: the white noise measured on
    the recorded poses (PoseNoise.none() where not measured), smoothed out of them when noise_smoothed_out;
    smoothing_error: the error the smoothing leaves in the poses, shared by those within its interval_s
    (PoseNoise.none() when not smoothed).
    """

    crs: CRS
    poses: PoseTrack
    scale_factor: np.ndarray
    convergence_deg: np.ndarray
    measured_noise: PoseNoise = field(default_factory=PoseNoise.none)
    noise_smoothed_out: bool = False
    smoothing_error: PoseNoise = field(default_factory=PoseNoise.none)

    def smoothed(self) -> WorldTrajectory:
        """The same trajectory with the white noise of its poses measured and, above the floor, smoothed out
        (trajectory_noise.smoothed_poses)."""
        poses, noise, left = smoothed_poses(self.poses)
        return replace(self, poses=poses, measured_noise=noise, noise_smoothed_out=poses is not self.poses,
                       smoothing_error=left)

    @property
    def white_noise(self) -> PoseNoise:
        """The white noise smoothed out of the poses (PoseNoise.none() where none was)."""
        return self.measured_noise if self.noise_smoothed_out else PoseNoise.none()

    @property
    def pose_noise(self) -> PoseNoise:
        """The white noise left in the poses: what was measured, none once smoothed out (what smoothing leaves is
        not white: smoothing_error)."""
        return PoseNoise.none() if self.noise_smoothed_out else self.measured_noise


def resolve_crs(spec: str, trajectory: Trajectory, source: str = "recording.yaml") -> CRS:
    """'auto' -> UTM zone of the first fix (geodetic trajectories only); else any projected CRS."""
    if spec == "auto":
        if not trajectory.geodetic:
            raise RecordingError(source, "crs is 'auto' but trajectory.csv is projected (x, y, z)",
                                 field="crs", expected="the projected CRS of the x, y columns, e.g. EPSG:32631")
        lat, lon = trajectory.position[0, :2]
        try:
            return utm_crs(lat_deg=lat, lon_deg=lon)
        except ValueError:
            raise RecordingError(source, f"crs is 'auto' but the first fix (lat {lat:g}, lon {lon:g}) is outside "
                                 "the UTM zones (80 S .. 84 N)", field="crs",
                                 expected="an explicit projected CRS, e.g. a polar stereographic one") from None
    try:
        crs = CRS.from_user_input(spec)
    except CRSError:
        raise RecordingError(source, f"unknown CRS {spec!r}", field="crs",
                             expected="'auto' or a projected CRS such as EPSG:32631 or EPSG:2154") from None
    if not crs.is_projected:
        raise RecordingError(source, f"CRS {spec!r} is not projected", field="crs",
                             expected="a projected CRS (metres), e.g. a UTM zone")
    units = {axis.unit_name for axis in crs.axis_info[:2]}
    if any(axis.unit_conversion_factor != 1.0 for axis in crs.axis_info[:2]):
        raise RecordingError(source, f"CRS {spec!r} has its grid in {', '.join(sorted(units))}", field="crs",
                             expected="a projected CRS in metres (the lidar measures metres)")
    return crs


def utm_crs(lat_deg: float, lon_deg: float) -> CRS:
    """The WGS84 UTM zone that contains (lat, lon); ValueError outside 80 S .. 84 N."""
    lat_deg, lon_deg = float(lat_deg), float(lon_deg)
    info = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(
        west_lon_degree=lon_deg, south_lat_degree=lat_deg, east_lon_degree=lon_deg, north_lat_degree=lat_deg))
    if not info:
        raise ValueError(f"lat {lat_deg:g}, lon {lon_deg:g} is in no UTM zone (80 S .. 84 N)")
    return CRS.from_epsg(int(info[0].code))


def map_factors(crs: CRS, lon_deg, lat_deg) -> tuple[np.ndarray, np.ndarray]:
    """(grid scale factor k, meridian convergence gamma [deg]) at geodetic points."""
    factors = Proj(crs).get_factors(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
    return np.asarray(factors.meridional_scale), np.asarray(factors.meridian_convergence)


def geodetic_to_grid(crs: CRS, lat_deg, lon_deg, alt_m) -> np.ndarray:
    """WGS84 (lat, lon deg, ellipsoidal height m) -> (N,3) grid x, y, z [m]."""
    to_grid = Transformer.from_crs(WGS84_3D, crs, always_xy=True)
    return np.column_stack(to_grid.transform(lon_deg, lat_deg, alt_m))


def grid_to_geodetic(crs: CRS, xyz_m) -> np.ndarray:
    """(N,3) grid x, y, z [m] -> (N,3) lat, lon [deg], ellipsoidal height [m]."""
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    to_geo = Transformer.from_crs(crs, WGS84_3D, always_xy=True)
    lon, lat, alt = to_geo.transform(xyz_m[:, 0], xyz_m[:, 1], xyz_m[:, 2])
    return np.column_stack([lat, lon, alt])


def enu_to_grid_rotation(convergence_deg) -> Rotation:
    """Rotation taking ENU-relative attitudes to grid-relative ones: Rz(gamma)."""
    return Rotation.from_euler("z", np.asarray(convergence_deg, dtype=np.float64)[..., None], degrees=True)


def to_world(trajectory: Trajectory, crs_spec: str, source: str = "recording.yaml") -> WorldTrajectory:
    """trajectory.csv -> T_world_body in the projected CRS (UTM zone of the first fix for 'auto')."""
    crs = resolve_crs(crs_spec, trajectory, source)
    if trajectory.geodetic:
        lat, lon, alt = trajectory.position.T
        position = geodetic_to_grid(crs, lat, lon, alt)
        scale, convergence = map_factors(crs, lon, lat)
        rotation = enu_to_grid_rotation(convergence) * rotation_from_rpy_deg(trajectory.rpy_deg)
    else:
        position = trajectory.position
        lat, lon, _ = grid_to_geodetic(crs, position).T
        scale, convergence = map_factors(crs, lon, lat)
        rotation = rotation_from_rpy_deg(trajectory.rpy_deg)
    return WorldTrajectory(crs, PoseTrack(trajectory.time, position, rotation), scale, convergence)
