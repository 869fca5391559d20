"""Ouster import: the real OS-1-128 / OS-0-128 captures of ouster-sdk against the SDK's own decoding and xyz.

The reference values (tests/data/ouster_sdk_reference.npz) come from ouster-sdk 1.0.1 run on the
same files (tools/ouster_sdk_reference.py): a sample of returns with the SDK's XYZLut xyz, and
packets the SDK encodes in the LEGACY and RNG19_RFL8_SIG16_NIR16 profiles.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.main import app
from graphcal.common.errors import RecordingError
from graphcal.importers.ouster_metadata import SECTIONS, read_ouster_metadata
from graphcal.importers.ouster_packets import decode_columns
from graphcal.importers.ouster_pcap import import_ouster, survey_ouster_pcap
from graphcal.recording.directory import Recording

FOLDER = Path(__file__).resolve().parents[2] / "shared/data/real/ouster_sdk_pcaps"
REFERENCE = np.load(Path(__file__).parent / "data/ouster_sdk_reference.npz")
CAPTURES = {"os1": ("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "OS-1-128_v2.3.0_1024x10.json"),
            "os0": ("OS-0-128-U1_v2.3.0_1024x10.pcap", "OS-0-128-U1_v2.3.0_1024x10.json")}
POSITION = (37.39, -122.08, 10.0)
needs_real = pytest.mark.skipif(not FOLDER.is_dir(), reason="shared real data absent")


def _paths(key):
    capture, meta = CAPTURES[key]
    return FOLDER / capture, FOLDER / meta


@needs_real
@pytest.mark.parametrize("key", CAPTURES)
def test_returns_and_xyz_match_ouster_sdk(key, tmp_path):
    capture, meta = _paths(key)
    metadata = read_ouster_metadata(meta)
    recording = import_ouster(capture, metadata, tmp_path / key, position=POSITION, quiet=True)
    returns = recording.points.read()
    ref = {name: REFERENCE[f"{key}_{name}"] for name in ("frame", "row", "column", "range_mm", "reflectivity",
                                                          "timestamp_ns", "xyz", "returns_per_frame")}
    np.testing.assert_array_equal(np.bincount(returns["scan"]), ref["returns_per_frame"])
    column = np.rint(returns["azimuth"].astype(np.float64) * 1024 / (2 * np.pi)).astype(np.int64)
    key_of = (returns["scan"].astype(np.int64) * 1024 + column) * 128 + returns["fibre"]
    order = np.argsort(key_of)
    found = order[np.searchsorted(key_of, (ref["frame"] * 1024 + ref["column"]) * 128 + ref["row"], sorter=order)]
    assert np.array_equal(key_of[found], (ref["frame"] * 1024 + ref["column"]) * 128 + ref["row"])
    np.testing.assert_allclose(returns["range"][found], ref["range_mm"] / 1000.0, atol=1e-6)
    np.testing.assert_array_equal(returns["intensity"][found], ref["reflectivity"])
    # per-return time: the column timestamp (ns) on the recording's clock
    stamps = ref["timestamp_ns"].astype(np.int64)
    t0 = returns["time"][found][np.argmin(stamps)]
    np.testing.assert_allclose(returns["time"][found] - t0, (stamps - stamps.min()) * 1e-9, atol=1e-7)
    # xyz in the Ouster sensor frame: the recording's sensor model, then its extrinsic (body = sensor frame here)
    fibre = returns["fibre"][found].astype(np.intp)
    p_lidar = recording.sensor.to_xyz(fibre, returns["range"][found].astype(np.float64),
                                      returns["azimuth"][found].astype(np.float64))
    p_sensor = recording.extrinsic.lidar_to_body(p_lidar)
    error = np.linalg.norm(p_sensor - ref["xyz"], axis=1)
    assert error.max() < 1e-3  # float32 range and azimuth in points.parquet: well under a millimetre
    # the model itself (float64 inputs) is the SDK's to numerical precision
    exact = recording.extrinsic.lidar_to_body(recording.sensor.to_xyz(fibre, ref["range_mm"] / 1000.0,
                                                                      2 * np.pi * ref["column"] / 1024))
    assert np.abs(exact - ref["xyz"]).max() < 1e-9


@needs_real
def test_import_streams_and_writes_what_the_whole_capture_gives(tmp_path):
    """Read 5000 bytes of the file at a time (one record a chunk: chunks without a lidar packet, frames and
    time order carried from chunk to chunk), the recording is the one of the whole file read at once, byte for
    byte, and holds the SDK's returns."""
    capture, meta = _paths("os1")
    metadata = read_ouster_metadata(meta)
    whole = import_ouster(capture, metadata, tmp_path / "whole", position=POSITION, chunk_bytes=None, quiet=True)
    streamed = import_ouster(capture, metadata, tmp_path / "streamed", position=POSITION, chunk_bytes=5000,
                             quiet=True)
    files = sorted(path.name for path in (tmp_path / "whole").iterdir())
    assert files == sorted(path.name for path in (tmp_path / "streamed").iterdir()) and "points.parquet" in files
    for name in files:
        assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "streamed" / name).read_bytes(), name
    returns = streamed.points.read()
    np.testing.assert_array_equal(np.bincount(returns["scan"]), REFERENCE["os1_returns_per_frame"])
    assert np.all(np.diff(returns["time"]) >= 0) and whole.source == streamed.source
    assert streamed.source["notes"][0].endswith(f"{len(returns['time'])} returns in 3 frames")


@needs_real
def test_a_capture_out_of_time_order_by_more_than_a_chunk_is_refused(tmp_path):
    """The lidar packets' records of the capture's second half written before the first half's: the streamed
    import names the time field and the order it expects, and writes nothing."""
    capture, meta = _paths("os0")
    data = capture.read_bytes()
    offsets, at = [], 24
    while at + 16 <= len(data):
        offsets.append(at)
        at += 16 + int.from_bytes(data[at + 8:at + 12], "little")
    offsets.append(len(data))
    records = [data[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
    half = len(records) // 2
    swapped = tmp_path / "swapped.pcap"
    swapped.write_bytes(data[:24] + b"".join(records[half:] + records[:half]))
    with pytest.raises(RecordingError, match="time.*lidar packets in time order"):
        import_ouster(swapped, read_ouster_metadata(meta), tmp_path / "rec", position=POSITION, chunk_bytes=50_000,
                      quiet=True)
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize("profile", ["LEGACY", "RNG19_RFL8_SIG16_NIR16"])
def test_other_profiles_decode_as_ouster_sdk_encodes_them(profile):
    packets = REFERENCE[f"{profile}_packets"]
    columns = decode_columns(packets, profile, 16, 128)
    np.testing.assert_array_equal(columns.range_mm, REFERENCE[f"{profile}_range_mm"])
    np.testing.assert_array_equal(columns.reflectivity, REFERENCE[f"{profile}_reflectivity"])
    np.testing.assert_array_equal(columns.timestamp_ns, REFERENCE[f"{profile}_timestamp_ns"])
    np.testing.assert_array_equal(columns.measurement_id, REFERENCE[f"{profile}_measurement_id"])
    assert np.all(columns.frame_id == REFERENCE[f"{profile}_frame_id"]) and columns.valid.all()


@needs_real
def test_sectioned_metadata_gives_the_same_model(tmp_path):
    _, meta = _paths("os0")
    flat = json.loads(meta.read_text())
    sectioned = {"lidar_data_format": flat["data_format"], "calibration_status": {}, "imu_intrinsics": {}}
    for name, value in flat.items():
        if name in SECTIONS:
            sectioned.setdefault(SECTIONS[name], {})[name] = value
    path = tmp_path / "sectioned.json"
    path.write_text(json.dumps(sectioned))
    a, b = read_ouster_metadata(meta).sensor_model(), read_ouster_metadata(path).sensor_model()
    assert a.to_dict() == b.to_dict() and b.beam_origin_m == pytest.approx(0.02767)


@needs_real
@pytest.mark.parametrize("change, field", [
    (lambda m: m.pop("beam_altitude_angles"), "beam_altitude_angles"),
    (lambda m: m["beam_azimuth_angles"].pop(), "beam_azimuth_angles"),
    (lambda m: m["data_format"].update(udp_profile_lidar="RNG19_RFL8_SIG16_NIR16_DUAL"), "udp_profile_lidar"),
    (lambda m: m.update(lidar_mode="fast"), "lidar_mode"),
    (lambda m: m["lidar_to_sensor_transform"].__setitem__(0, 2), "lidar_to_sensor_transform"),
    (lambda m: m.update(lidar_origin_to_beam_origin_mm="15.8"), "lidar_origin_to_beam_origin_mm"),
])
def test_bad_metadata_is_refused_naming_the_field(tmp_path, change, field):
    _, meta = _paths("os1")
    data = json.loads(meta.read_text())
    change(data)
    path = tmp_path / "meta.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RecordingError, match=field):
        read_ouster_metadata(path)


@needs_real
def test_a_capture_and_the_metadata_of_another_unit_are_refused():
    capture, _ = _paths("os1")
    _, other = _paths("os0")
    with pytest.raises(RecordingError, match="prod_sn"):
        survey_ouster_pcap(capture, read_ouster_metadata(other))


@needs_real
def test_cli_imports_a_capture(tmp_path):
    capture, meta = _paths("os0")
    out = tmp_path / "os0"
    runner = CliRunner()
    result = runner.invoke(app, ["import", "ouster", str(capture), "--metadata", str(meta), "--position",
                                 "37.39,-122.08,10", "--boresight", "0,0,90", "--out", str(out)])
    assert result.exit_code == 0, result.output
    recording = Recording.load(out)
    assert len(recording.points) == REFERENCE["os0_returns_per_frame"].sum()
    assert recording.sensor.model == "OS-0-128" and recording.sensor.beam_origin_m == pytest.approx(0.02767)
    # sensor -> body yaw 90 deg after the lidar -> sensor 180 deg: -90 deg; the 36.18 mm lever arm stays vertical
    np.testing.assert_allclose(recording.extrinsic.boresight_deg, (0.0, 0.0, -90.0), atol=1e-9)
    np.testing.assert_allclose(recording.extrinsic.lever_arm_m, (0.0, 0.0, 0.03618), atol=1e-12)
    again = runner.invoke(app, ["import", "ouster", str(capture), "--metadata", str(meta), "--position",
                                "37.39,-122.08,10", "--out", str(out)])
    assert again.exit_code == 2 and "already exists" in again.output
    missing = runner.invoke(app, ["import", "ouster", str(capture), "--metadata", str(tmp_path / "no.json"),
                                  "--position", "37.39,-122.08,10", "--out", str(tmp_path / "x")])
    assert missing.exit_code == 2 and "no.json: file not found" in missing.output
