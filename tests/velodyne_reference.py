"""velodyne-decoder (the reference decoder of the importer tests) on raw 1206-byte Velodyne packets."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def reference_xyz(packets: np.ndarray, stamps: np.ndarray, model: str, calibration: Path) -> np.ndarray:
    """The x, y, z [m, sensor frame] velodyne-decoder gives for the packets with their stamps [s], the head
    `model` (a velodyne_decoder.Model name, e.g. VLP16) and its calibration file, no range limit."""
    import velodyne_decoder as vd

    config = vd.Config()
    config.model, config.calibration = getattr(vd.Model, model), vd.Calibration.read(str(calibration))
    config.min_range, config.max_range = 0.0, 1000.0
    decoder, clouds = vd.StreamDecoder(config), []
    for stamp, data in zip(stamps, packets.view(np.uint8).reshape(-1, 1206)):
        clouds.append(decoder.decode(float(stamp), data.tobytes(), False))
    clouds.append(decoder.finish(False))
    return np.concatenate([cloud[1] for cloud in clouds if cloud is not None])[:, :3]


def decoder_minus_model(sensor, fibre, azimuth_rad):
    """velodyne-decoder 3.1 (like the HDL-64E manual) puts the vertical offset V straight up
    (xy = D cos e, z = D sin e + V); graphcal's model (like ROS velodyne_pointcloud) shifts the beam
    by V perpendicular to it. The difference, decoder minus graphcal, in graphcal's sensor frame."""
    v, e = sensor.vertical_offset_m[fibre], np.radians(sensor.elevation_deg[fibre])
    a = azimuth_rad + np.radians(sensor.azimuth_offset_deg[fibre])
    return np.column_stack([v * np.sin(e) * np.cos(a), -v * np.sin(e) * np.sin(a), v * (1.0 - np.cos(e))])
