"""Ouster JSON export: the real metadata files read and written back, and a calibration's angles in them."""

import json
from pathlib import Path

import numpy as np
import pytest

from graphcal.common.errors import ConfigError
from graphcal.importers.ouster_json import DECIMALS, ouster_metadata, write_ouster_json
from graphcal.importers.ouster_metadata import read_ouster_metadata

FOLDER = Path(__file__).resolve().parents[2] / "shared/data/real/ouster_sdk_pcaps"
FILES = sorted(FOLDER.glob("*.json")) if FOLDER.is_dir() else []
needs_real = pytest.mark.skipif(not FILES, reason="shared real data absent")


def _ouster_xyz(metadata: dict, column: np.ndarray, beam: np.ndarray, range_mm: np.ndarray) -> np.ndarray:
    """The Ouster documented formula (lidar frame, mm), written out from the JSON's own fields."""
    altitude = np.radians(np.asarray(metadata["beam_altitude_angles"]))[beam]
    azimuth = -np.radians(np.asarray(metadata["beam_azimuth_angles"]))[beam]
    n = metadata["lidar_origin_to_beam_origin_mm"]
    encoder = 2 * np.pi * (1 - column / 1024)
    return np.column_stack([(range_mm - n) * np.cos(encoder + azimuth) * np.cos(altitude) + n * np.cos(encoder),
                            (range_mm - n) * np.sin(encoder + azimuth) * np.cos(altitude) + n * np.sin(encoder),
                            (range_mm - n) * np.sin(altitude)])


@needs_real
@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_each_real_metadata_round_trips(path, tmp_path):
    metadata = read_ouster_metadata(path)
    sensor = metadata.sensor_model()
    out = tmp_path / "written.json"
    notes = write_ouster_json(out, sensor, np.zeros((sensor.n_fibres, 4)), metadata.raw)
    assert notes == []
    written = json.loads(out.read_text())
    assert written == json.loads(path.read_text())  # every field, the angles to the file's own digits
    again = read_ouster_metadata(out).sensor_model()
    assert again.to_dict() == sensor.to_dict()


@needs_real
def test_a_calibration_changes_only_the_beam_angles_and_its_points_follow():
    metadata = read_ouster_metadata(FILES[-1])
    sensor = metadata.sensor_model()
    rng = np.random.default_rng(4)
    offsets = np.column_stack([np.zeros(128), np.radians(rng.normal(0, 0.05, 128)),
                               np.radians(rng.normal(0, 0.05, 128)), np.zeros(128)])
    written, notes = ouster_metadata(sensor, offsets, metadata.raw)
    assert notes == []
    changed = {name for name in written if written[name] != metadata.raw[name]}
    assert changed == {"beam_altitude_angles", "beam_azimuth_angles"}
    np.testing.assert_allclose(written["beam_azimuth_angles"], metadata.azimuth_deg + np.degrees(offsets[:, 1]),
                               atol=10 ** -DECIMALS)
    # the calibrated graphcal model and the Ouster formula on the written JSON give the same points
    column, beam = rng.integers(0, 1024, 500), rng.integers(0, 128, 500)
    range_mm = rng.uniform(500, 80000, 500)
    ours = sensor.to_xyz(beam, range_mm / 1000, 2 * np.pi * column / 1024, offsets) * 1000
    np.testing.assert_allclose(_ouster_xyz(written, column, beam, range_mm), ours, atol=0.02)  # mm, 6 decimals


@needs_real
def test_range_and_height_offsets_are_noted_as_left_out():
    metadata = read_ouster_metadata(FILES[0])
    sensor = metadata.sensor_model()
    offsets = np.zeros((128, 4))
    offsets[5, 0], offsets[9, 3] = 0.012, -0.004
    _, notes = ouster_metadata(sensor, offsets, metadata.raw)
    assert any("d_range_m" in note and "12.0 mm" in note for note in notes)
    assert any("h_z_m" in note and "4.0 mm" in note for note in notes)


@needs_real
def test_without_the_original_the_beam_intrinsics_are_written():
    metadata = read_ouster_metadata(FILES[0])
    sensor = metadata.sensor_model()
    written, _ = ouster_metadata(sensor, np.zeros((128, 4)))
    beams = written["beam_intrinsics"]
    assert beams["beam_altitude_angles"] == metadata.raw["beam_altitude_angles"]
    assert beams["lidar_origin_to_beam_origin_mm"] == pytest.approx(metadata.raw["lidar_origin_to_beam_origin_mm"])
    assert beams["beam_to_lidar_transform"][3] == pytest.approx(metadata.raw["lidar_origin_to_beam_origin_mm"])


@needs_real
def test_the_metadata_of_another_head_is_refused():
    metadata = read_ouster_metadata(FILES[0])
    sensor = metadata.sensor_model()
    smaller = dict(metadata.raw, beam_altitude_angles=metadata.raw["beam_altitude_angles"][:64])
    with pytest.raises(ConfigError, match="beam_altitude_angles has 64 beams"):
        ouster_metadata(sensor, np.zeros((128, 4)), smaller)
