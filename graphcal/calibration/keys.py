"""The GTSAM keys of a calibration: per-fibre intrinsic offsets I(fibre) (Vector4: d_range m,
d_azimuth rad, d_elevation rad, Hz m), the extrinsic E(0) (Pose3 T_body_lidar) and the trajectory
corrections X(control) (Point3, or Pose3 about the vehicle in world axes)."""

import gtsam

I = gtsam.symbol_shorthand.I
E = gtsam.symbol_shorthand.E
X = gtsam.symbol_shorthand.X
