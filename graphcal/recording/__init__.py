"""The recording: the directory of RECORDING.md (points, sensor model, extrinsic, trajectory, odometry,
truth), the sensor model (eq. 4.1/4.2), georeferencing and geodesy, and what a recording measures of
itself (range noise, the trajectory's jitter)."""
