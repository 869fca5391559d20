"""Raw returns -> world points: sensor model (eq. 4.2) -> extrinsic -> trajectory at each return's time.

p_world = R_world_body(t) (R_body_lidar p_lidar + T_body_lidar) + X_world_body(t), with every
return placed at its own time t (so motion during the sweep is accounted for).
"""

from __future__ import annotations

import numpy as np

from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.poses import PoseTrack
from graphcal.recording.sensor import SensorModel


def georeference(time_s, fibre, range_m, azimuth_rad, sensor: SensorModel, extrinsic: Extrinsic,
                 poses: PoseTrack, offsets: np.ndarray | None = None) -> np.ndarray:
    """(N,) raw returns -> (N,3) world xyz [m]. offsets: (n_fibres, 4) (m, rad, rad, m) or None."""
    p_lidar = sensor.to_xyz(np.asarray(fibre, dtype=np.intp), range_m, azimuth_rad, offsets)
    return poses.transform(time_s, extrinsic.lidar_to_body(p_lidar))


def georeference_batches(points, sensor, extrinsic, poses, offsets=None):
    """Iterate world xyz (float64, m) batch by batch over a PointTable."""
    for batch in points.iter_batches(["time", "fibre", "range", "azimuth"]):
        yield georeference(batch["time"], batch["fibre"], batch["range"], batch["azimuth"],
                           sensor, extrinsic, poses, offsets)
