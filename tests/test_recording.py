"""The recording directory contract (RECORDING.md): round trips, bad inputs, chunked validation,
atomic save."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import yaml

import graphcal
import graphcal.common.atomic
import graphcal.recording.points
from graphcal import Recording, RecordingError
from graphcal.recording.odometry import Odometry
from graphcal.recording.points import PointTable
from graphcal.simulation.drive import Drive, straight, turn
from graphcal.simulation.scenario import ExtrinsicSpec, IntrinsicErrors, Scenario
from graphcal.simulation.scene import street

# points.parquet column types of RECORDING.md
CONTRACT_DTYPES = {"time": np.float64, "fibre": np.int16, "range": np.float32, "azimuth": np.float32,
                   "intensity": np.float32, "scan": np.int32}


def scenario(trajectory_format: str = "projected") -> Scenario:
    """A small drive with non-zero true intrinsics and extrinsic error, so truth/ is not all zeros."""
    return Scenario(name="t", duration_s=1.0, size=0.1, scene=street(60, 16),
                    drive=Drive(segments=straight(3) + turn(20, 10), speed_knots=[(0, 5.0)]),
                    intrinsic_errors=IntrinsicErrors(range_m=0.02, azimuth_deg=0.2, elevation_deg=0.1, h_z_m=0.01),
                    extrinsic=ExtrinsicSpec(error_lever_arm_m=(0.01, -0.02, 0.03),
                                            error_boresight_deg=(0.1, -0.2, 0.3)),
                    trajectory_format=trajectory_format)


def save_copy(recording: Recording, path: Path, **changes) -> Path:
    """Save a shallow copy: Recording.save repoints `points` to the file it wrote, and the
    original must keep its in-memory points to be compared with what is read back."""
    return dataclasses.replace(recording, **changes).save(path)


@pytest.fixture(scope="module")
def simulated() -> Recording:
    """A simulated recording, points in memory (never saved itself)."""
    return graphcal.simulate(scenario(), quiet=True)


@pytest.fixture(scope="module")
def valid_dir(simulated, tmp_path_factory) -> Path:
    """A valid recording on disk, shared read-only by the tests of this module."""
    return save_copy(simulated, tmp_path_factory.mktemp("valid") / "rec")


@pytest.fixture(scope="module")
def simulated_geodetic() -> Recording:
    """The same drive with a lat/lon trajectory.csv (crs kept explicit)."""
    return graphcal.simulate(scenario("geodetic"), quiet=True)


@pytest.fixture
def geodetic_dir(simulated_geodetic, tmp_path) -> Path:
    return save_copy(simulated_geodetic, tmp_path / "rec")


@pytest.fixture
def rec_dir(valid_dir, tmp_path) -> Path:
    """A private copy of the valid recording, for a test to damage."""
    return Path(shutil.copytree(valid_dir, tmp_path / "rec"))


def load_error(path: Path, file: str, *fragments: str) -> RecordingError:
    """Load `path`, expect a RecordingError naming `file` and containing every fragment."""
    with pytest.raises(RecordingError, match=re.escape(file)) as info:
        Recording.load(path)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return info.value


def file_digest(directory: Path) -> dict[str, str]:
    return {str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(directory.rglob("*")) if p.is_file()}


# --- round trips ---------------------------------------------------------------------------
def assert_same_trajectory(a, b, position_atol: float) -> None:
    assert a.geodetic == b.geodetic
    np.testing.assert_allclose(a.time, b.time, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.position, b.position, rtol=0, atol=position_atol)
    np.testing.assert_allclose(a.rpy_deg, b.rpy_deg, rtol=0, atol=1e-8)


def assert_same_recording(original: Recording, loaded: Recording) -> None:
    assert loaded.name == original.name and loaded.crs == original.crs
    for name in ("model", "rotation_hz", "reference_fibre"):
        assert getattr(loaded.sensor, name) == getattr(original.sensor, name)
    for name in ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m", "horizontal_offset_m"):
        np.testing.assert_array_equal(getattr(loaded.sensor, name), getattr(original.sensor, name))
    assert loaded.extrinsic == original.extrinsic
    # lat/lon are written with 1e-10 deg (~1e-5 m), grid coordinates with 1e-6 m
    assert_same_trajectory(loaded.trajectory, original.trajectory,
                           position_atol=2e-10 if original.trajectory.geodetic else 1e-6)

    assert original.points.path is None and loaded.points.path == loaded.path / "points.parquet"
    expected, got = original.points.read(), loaded.points.read()
    assert sorted(got) == sorted(CONTRACT_DTYPES)
    for name, dtype in CONTRACT_DTYPES.items():
        assert got[name].dtype == dtype, name
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)

    true, loaded_truth = original.truth, loaded.truth
    assert loaded_truth is not None
    np.testing.assert_allclose(loaded_truth.intrinsics, true.intrinsics, rtol=1e-8, atol=1e-12)
    assert np.abs(true.intrinsics).max() > 0, "the scenario should have non-zero true offsets"
    assert loaded_truth.extrinsic == true.extrinsic
    assert_same_trajectory(loaded_truth.trajectory, true.trajectory,
                           position_atol=2e-10 if true.trajectory.geodetic else 1e-6)
    assert loaded_truth.effects == true.effects
    np.testing.assert_array_equal(loaded_truth.world_points(), true.world_points())


def test_round_trip(simulated, valid_dir):
    loaded = Recording.load(valid_dir)
    assert_same_recording(simulated, loaded)
    assert loaded.odometry is None
    summary = loaded.validate()
    time = simulated.points.read(["time"])["time"]
    fibre = simulated.points.read(["fibre"])["fibre"]
    assert summary.n_points == len(time) == len(loaded.points)
    assert (summary.time_min, summary.time_max) == (time.min(), time.max())
    np.testing.assert_array_equal(summary.count_per_fibre, np.bincount(fibre, minlength=32))


def test_round_trip_geodetic(simulated_geodetic, geodetic_dir):
    assert simulated_geodetic.trajectory.geodetic and simulated_geodetic.crs == "EPSG:32631"
    assert_same_recording(simulated_geodetic, Recording.load(geodetic_dir))
    assert (geodetic_dir / "trajectory.csv").read_text().startswith("time,lat,lon,alt,roll,pitch,yaw\n")
    assert yaml.safe_load((geodetic_dir / "recording.yaml").read_text())["crs"] == "EPSG:32631"


def make_odometry(time: np.ndarray, with_gyro: bool) -> Odometry:
    return Odometry(time=time, wheel_left_rad=np.linspace(0.0, 16.1, len(time)),
                    wheel_right_rad=np.linspace(0.0, 16.3, len(time)), wheel_radius_m=0.31, track_m=1.6,
                    yaw_rate_rad_s=np.sin(time) * 0.1 if with_gyro else None)


@pytest.mark.parametrize("with_gyro", [False, True])
def test_round_trip_odometry(simulated, tmp_path, with_gyro):
    time = np.arange(1000.0, 1001.0 + 1e-9, 0.02)
    odometry = make_odometry(time, with_gyro)
    path = save_copy(simulated, tmp_path / "rec", odometry=odometry)
    manifest = yaml.safe_load((path / "recording.yaml").read_text())
    assert manifest["odometry"] == {"wheel_radius_m": 0.31, "track_m": 1.6}
    loaded = Recording.load(path)
    assert_same_recording(simulated, loaded)
    got = loaded.odometry
    assert (got.wheel_radius_m, got.track_m) == (0.31, 1.6)
    for name in ("time", "wheel_left_rad", "wheel_right_rad"):
        np.testing.assert_allclose(getattr(got, name), getattr(odometry, name), rtol=0, atol=1e-9)
    if with_gyro:
        np.testing.assert_allclose(got.yaw_rate_rad_s, odometry.yaw_rate_rad_s, rtol=0, atol=1e-9)
    else:
        assert got.yaw_rate_rad_s is None


@pytest.mark.parametrize("model", ["HDL-32E", "VLP-16", "HDL-64E"])
def test_sensor_yaml_round_trip(model, tmp_path):
    """Every catalogue model, including the HDL-64E's optional per-fibre factory terms."""
    sensor = graphcal.sensor_from_catalog(model, rotation_hz=12.5)
    path = tmp_path / "sensor.yaml"
    path.write_text(yaml.safe_dump(sensor.to_dict()))
    loaded = graphcal.SensorModel.from_dict(yaml.safe_load(path.read_text()), path)
    assert (loaded.model, loaded.rotation_hz, loaded.reference_fibre) == (model, 12.5, sensor.reference_fibre)
    assert loaded.timing == sensor.timing
    for name in ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m", "horizontal_offset_m"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(sensor, name))
    if model == "HDL-64E":
        assert np.abs(loaded.horizontal_offset_m).max() == pytest.approx(0.026)


def test_round_trip_of_a_loaded_recording_onto_itself(valid_dir, rec_dir, simulated):
    """Saving a recording onto the directory its points are read from must not lose them."""
    Recording.load(rec_dir).save(rec_dir)
    assert_same_recording(simulated, Recording.load(rec_dir))
    assert file_digest(rec_dir) == file_digest(valid_dir)


# --- bad inputs: the directory and points.parquet --------------------------------------------
def test_missing_directory(tmp_path):
    error = load_error(tmp_path / "nowhere", "nowhere", "recording directory not found")
    assert error.path == tmp_path / "nowhere"


def test_missing_points(rec_dir):
    (rec_dir / "points.parquet").unlink()
    load_error(rec_dir, "points.parquet", "file not found")


def test_points_not_parquet(rec_dir):
    (rec_dir / "points.parquet").write_text("time,fibre\n1.0,2\n")
    load_error(rec_dir, "points.parquet", "not a Parquet file")


def test_damaged_points(rec_dir):
    """Bytes overwritten in the middle of points.parquet (a flipped sector): the read fails naming the file."""
    path = rec_dir / "points.parquet"
    data = bytearray(path.read_bytes())
    for where in (0.3, 0.5, 0.7):
        start = int(len(data) * where)
        data[start:start + 256] = bytes(range(256))
    path.write_bytes(bytes(data))
    load_error(rec_dir, "points.parquet", "damaged Parquet data")


def test_binary_recording_yaml(rec_dir):
    (rec_dir / "recording.yaml").write_bytes(bytes(range(128, 256)) * 4)
    load_error(rec_dir, "recording.yaml", "not a UTF-8 text file")


def rewrite_points(rec_dir: Path, change) -> None:
    path = rec_dir / "points.parquet"
    pq.write_table(change(pq.read_table(path)), path)


def set_column(table: pa.Table, name: str, values) -> pa.Table:
    return table.set_column(table.schema.get_field_index(name), name, pa.array(values))


def set_value(table: pa.Table, name: str, row: int, value) -> pa.Table:
    values = table.column(name).to_numpy().copy()
    values[row] = value
    return set_column(table, name, pa.array(values, type=table.schema.field(name).type))


@pytest.mark.parametrize("change, field, fragments", [
    (lambda t: t.drop_columns(["range"]), "range", ["missing column", "expected a column of type float32"]),
    (lambda t: t.drop_columns(["fibre"]), "fibre", ["missing column", "int16"]),
    (lambda t: set_column(t, "range", pc.cast(t.column("range"), pa.string())), "range",
     ["column type is string", "expected float32"]),
    (lambda t: set_column(t, "time", pc.cast(t.column("time"), pa.float32())), "time",
     ["column type is float32", "expected float64"]),
    (lambda t: set_column(t, "fibre", pc.cast(t.column("fibre"), pa.float32())), "fibre",
     ["column type is float32", "expected int16"]),
], ids=["missing-range", "missing-fibre", "range-string", "time-float32", "fibre-float"])
def test_bad_point_column(rec_dir, change, field, fragments):
    rewrite_points(rec_dir, change)
    error = load_error(rec_dir, "points.parquet", f"field '{field}'", *fragments)
    assert error.field == field


def test_optional_scan_column_may_be_absent_and_other_int_float_widths_are_accepted(rec_dir, simulated):
    def change(table):
        table = table.drop_columns(["scan"])
        table = set_column(table, "fibre", pc.cast(table.column("fibre"), pa.int64()))
        return set_column(table, "range", pc.cast(table.column("range"), pa.float64()))

    rewrite_points(rec_dir, change)
    loaded = Recording.load(rec_dir)
    assert "scan" not in loaded.points.column_names
    # written back with the contract's types
    loaded.save(rec_dir)
    schema = pq.read_schema(rec_dir / "points.parquet")
    assert (schema.field("fibre").type, schema.field("range").type) == (pa.int16(), pa.float32())
    expected, got = simulated.points.read(), Recording.load(rec_dir).points.read()
    for name in ("time", "fibre", "range", "azimuth", "intensity"):
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)


@pytest.mark.parametrize("column, row, value, fragments", [
    ("range", 123, np.nan, ["value nan at row index 123", "expected finite numbers"]),
    ("intensity", 4567, np.inf, ["value inf at row index 4567", "expected finite numbers"]),
    ("azimuth", 77, -np.inf, ["value -inf at row index 77", "expected finite numbers"]),
    ("time", 10, np.nan, ["value nan at row index 10", "expected finite numbers"]),
    ("range", 999, -1.5, ["negative range -1.5 at row index 999", "expected ranges >= 0 m"]),
    ("range", 998, 787762.0, ["range 787762.0 at row index 998", "within 100,000 m"]),  # a flipped exponent bit
    ("fibre", 321, 40, ["fibre id 40 at row index 321", "0..31"]),
    ("fibre", 322, -1, ["fibre id -1 at row index 322", "0..31"]),
    ("intensity", 55, 300.0, ["intensity 300.0 at row index 55", "reflectivity within 0-255"]),
], ids=["range-nan", "intensity-inf", "azimuth-minus-inf", "time-nan", "negative-range", "range-beyond", "fibre-40",
        "fibre-negative", "intensity-above-255"])
def test_bad_point_value(rec_dir, column, row, value, fragments):
    rewrite_points(rec_dir, lambda table: set_value(table, column, row, value))
    error = load_error(rec_dir, "points.parquet", f"field '{column}'", *fragments)
    assert error.field == column


def test_null_in_integer_column(rec_dir):
    """A Parquet null (e.g. an importer's missing fibre) must not slip through as a fibre id."""
    def change(table):
        fibre = table.column("fibre").to_pylist()
        fibre[250] = None
        return set_column(table, "fibre", pa.array(fibre, type=pa.int16()))

    rewrite_points(rec_dir, change)
    load_error(rec_dir, "points.parquet", "field 'fibre'", "at row index 250", "expected finite numbers")


def test_azimuth_in_degrees(rec_dir):
    rewrite_points(rec_dir, lambda t: set_column(t, "azimuth", pc.multiply(t.column("azimuth"),
                                                                           pa.scalar(180 / np.pi, pa.float32()))))
    load_error(rec_dir, "points.parquet", "field 'azimuth'", "radians", "degrees given?")


def swap_rows(rec_dir: Path, i: int, j: int) -> tuple[float, float]:
    """Swap two rows of points.parquet; return their (distinct) times."""
    def change(table):
        order = np.arange(table.num_rows)
        order[[i, j]] = order[[j, i]]
        return table.take(pa.array(order))

    time = pq.read_table(rec_dir / "points.parquet", columns=["time"]).column("time").to_numpy()
    assert time[i] < time[j]
    rewrite_points(rec_dir, change)
    return float(time[i]), float(time[j])


def test_unsorted_time(rec_dir):
    """Rows 500 and 600 swapped: row 501 is the first one earlier than its predecessor."""
    _, later = swap_rows(rec_dir, 500, 600)
    time = pq.read_table(rec_dir / "points.parquet", columns=["time"]).column("time").to_numpy()
    error = load_error(rec_dir, "points.parquet", "field 'time'",
                       f"time {float(time[501])!r} at row index 501 is before {later!r}",
                       "expected rows sorted by time")
    assert error.field == "time"


def test_fibre_not_in_sensor_yaml(rec_dir):
    """A sensor.yaml with fewer fibres than the points use: the fibre id is named."""
    sensor = yaml.safe_load((rec_dir / "sensor.yaml").read_text())
    sensor["fibres"] = sensor["fibres"][:20]
    (rec_dir / "sensor.yaml").write_text(yaml.safe_dump(sensor))
    fibre = pq.read_table(rec_dir / "points.parquet", columns=["fibre"]).column("fibre").to_numpy()
    first = int(np.flatnonzero(fibre >= 20)[0])
    load_error(rec_dir, "points.parquet", "field 'fibre'", f"fibre id {fibre[first]} at row index {first}",
               "expected an id of sensor.yaml, 0..19")


def test_no_returns(rec_dir):
    rewrite_points(rec_dir, lambda t: t.slice(0, 0))
    load_error(rec_dir, "points.parquet", "no returns", "expected at least one row")


# --- bad inputs: trajectory.csv --------------------------------------------------------------
def trajectory_lines(rec_dir: Path) -> list[str]:
    return (rec_dir / "trajectory.csv").read_text().splitlines()


def write_trajectory(rec_dir: Path, lines: list[str]) -> None:
    (rec_dir / "trajectory.csv").write_text("\n".join(lines) + "\n")


def test_trajectory_does_not_cover_points(rec_dir):
    lines = trajectory_lines(rec_dir)
    write_trajectory(rec_dir, lines[: len(lines) // 2])
    end = float(lines[len(lines) // 2 - 1].split(",")[0])
    error = load_error(rec_dir, "trajectory.csv", "field 'time'", f"{end:.6f}]",
                       "expected poses covering the returns' span")
    assert error.field == "time"


def test_bad_trajectory_header(rec_dir):
    lines = trajectory_lines(rec_dir)
    write_trajectory(rec_dir, [lines[0].replace("yaw", "heading")] + lines[1:])
    load_error(rec_dir, "trajectory.csv", "header is time,x,y,z,roll,pitch,heading", "missing column 'yaw'",
               "expected header time,lat,lon,alt,roll,pitch,yaw or time,x,y,z,roll,pitch,yaw")


def test_bad_trajectory_header_geodetic(geodetic_dir):
    lines = trajectory_lines(geodetic_dir)
    write_trajectory(geodetic_dir, [lines[0].replace("lon", "long")] + lines[1:])
    load_error(geodetic_dir, "trajectory.csv", "missing column 'lon'")


@pytest.mark.parametrize("row, column, value, fragments", [
    (5, "x", "abc", ["value 'abc'", "expected a number"]),
    (17, "yaw", "", ["empty value", "expected a number"]),
    (42, "z", "nan", ["value nan", "expected a finite number"]),
    (3, "pitch", "inf", ["value inf", "expected a finite number"]),
    (8, "roll", "N/A", ["value 'N/A'", "expected a number"]),
], ids=["text", "empty", "nan", "inf", "n/a"])
def test_bad_trajectory_value(rec_dir, row, column, value, fragments):
    lines = trajectory_lines(rec_dir)
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    write_trajectory(rec_dir, lines)
    error = load_error(rec_dir, "trajectory.csv", f"field '{column}', row {row}", *fragments)
    assert (error.field, error.row) == (column, row)


@pytest.mark.parametrize("delta", [0.0, -0.5], ids=["repeated", "decreasing"])
def test_trajectory_time_not_increasing(rec_dir, delta):
    lines = trajectory_lines(rec_dir)
    cells = lines[10].split(",")
    cells[0] = f"{float(lines[9].split(',')[0]) + delta:.9f}"
    lines[10] = ",".join(cells)
    write_trajectory(rec_dir, lines)
    error = load_error(rec_dir, "trajectory.csv", "field 'time', row 10", "does not increase",
                       "expected strictly increasing times")
    assert error.row == 10


def test_trajectory_latitude_out_of_range(geodetic_dir):
    lines = trajectory_lines(geodetic_dir)
    cells = lines[7].split(",")
    cells[1] = "4200.0"
    lines[7] = ",".join(cells)
    write_trajectory(geodetic_dir, lines)
    load_error(geodetic_dir, "trajectory.csv", "field 'lat', row 7", "value 4200.0", "degrees within +-90")


def test_trajectory_with_one_pose(rec_dir):
    write_trajectory(rec_dir, trajectory_lines(rec_dir)[:2])
    load_error(rec_dir, "trajectory.csv", "1 pose(s)", "at least 2 poses")


# --- bad inputs: the YAML files --------------------------------------------------------------
def edit_yaml(rec_dir: Path, name: str, change) -> None:
    path = rec_dir / name
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data))


def set_key(key, value):
    return lambda data: data.__setitem__(key, value)


def drop_key(key):
    return lambda data: data.pop(key)


def drop_fibre_key(index, key):
    return lambda data: data["fibres"][index].pop(key)


P = pytest.param
BAD_YAML = [
    P("recording.yaml", set_key("crs", "EPSG:999999"), "crs", ["unknown CRS 'EPSG:999999'", "projected CRS"],
      id="crs-unknown-epsg"),
    P("recording.yaml", set_key("crs", "not a crs"), "crs", ["unknown CRS 'not a crs'"], id="crs-garbage"),
    P("recording.yaml", set_key("crs", "auto"), "crs",
      ["'auto' but trajectory.csv is projected", "expected the projected CRS"], id="crs-auto-projected"),
    P("recording.yaml", set_key("crs", "EPSG:4326"), "crs",
      ["'EPSG:4326' is not projected", "expected a projected CRS"], id="crs-geographic"),
    P("recording.yaml", set_key("crs", "EPSG:2263"), "crs",
      ["'EPSG:2263' has its grid in US survey foot", "expected a projected CRS in metres"], id="crs-feet"),
    P("recording.yaml", set_key("format", "graphcal-recording/2"), "format",
      ["format is 'graphcal-recording/2'", "expected graphcal-recording/1"], id="format-version"),
    P("recording.yaml", drop_key("format"), "format", ["format is None", "expected graphcal-recording/1"],
      id="format-missing"),
    P("sensor.yaml", drop_fibre_key(3, "elevation_deg"), "fibres", ["row 3", "missing elevation_deg", "expected"],
      id="sensor-missing-elevation"),
    P("sensor.yaml", set_key("reference_fibre", 32), "reference_fibre",
      ["reference_fibre is 32", "expected a fibre id in 0..31"], id="sensor-reference-32"),
    P("sensor.yaml", set_key("reference_fibre", -1), "reference_fibre", ["expected a fibre id in 0..31"],
      id="sensor-reference-negative"),
    P("sensor.yaml", set_key("reference_fibre", True), "reference_fibre", ["expected a fibre id in 0..31"],
      id="sensor-reference-bool"),
    P("sensor.yaml", set_key("rotation_hz", 0), "rotation_hz", ["expected a positive rate in Hz"],
      id="sensor-rotation-zero"),
    P("sensor.yaml", set_key("rotation_hz", "fast"), "rotation_hz", ["value 'fast'", "expected a finite number"],
      id="sensor-rotation-text"),
    P("sensor.yaml", drop_key("fibres"), "fibres", ["missing field", "expected"], id="sensor-no-fibres"),
    P("sensor.yaml", lambda d: d["fibres"][5].__setitem__("id", 6), "fibres", ["row 5", "expected id 5"],
      id="sensor-fibre-id"),
    P("sensor.yaml", lambda d: d["fibres"][2].__setitem__("elevation_deg", "low"), "fibres[2].elevation_deg",
      ["value 'low'", "expected a finite number"], id="sensor-elevation-text"),
    P("extrinsic.yaml", set_key("lever_arm_m", [0.8, 0.0]), "lever_arm_m",
      ["value [0.8, 0.0]", "expected a list of 3 finite numbers"], id="extrinsic-2-values"),
    P("extrinsic.yaml", set_key("boresight_deg", [0.0, "x", 90.0]), "boresight_deg",
      ["expected a list of 3 finite numbers"], id="extrinsic-text"),
    P("extrinsic.yaml", set_key("boresight_deg", [0.0, float("nan"), 90.0]), "boresight_deg",
      ["expected a list of 3 finite numbers"], id="extrinsic-nan"),
    P("extrinsic.yaml", drop_key("lever_arm_m"), "lever_arm_m", ["missing field", "expected a list of 3 numbers"],
      id="extrinsic-missing"),
]


@pytest.mark.parametrize("file, change, field, fragments", BAD_YAML)
def test_bad_yaml_field(rec_dir, file, change, field, fragments):
    edit_yaml(rec_dir, file, change)
    error = load_error(rec_dir, file, f"field '{field}'", *fragments)
    assert error.field == field and error.path == rec_dir / file


@pytest.mark.parametrize("file", ["recording.yaml", "sensor.yaml", "extrinsic.yaml"])
def test_invalid_yaml(rec_dir, file):
    (rec_dir / file).write_text("format: [graphcal-recording/1\nname: x\n")
    load_error(rec_dir, file, "not valid YAML at line 2, column 5: expected ',' or ']', but got ':'")


@pytest.mark.parametrize("file", ["recording.yaml", "sensor.yaml", "extrinsic.yaml", "trajectory.csv"])
def test_missing_required_file(rec_dir, file):
    (rec_dir / file).unlink()
    load_error(rec_dir, file, "file not found")


@pytest.mark.parametrize("file", ["sensor.yaml", "extrinsic.yaml"])
def test_yaml_not_a_mapping(rec_dir, file):
    (rec_dir / file).write_text("- 1\n- 2\n")
    load_error(rec_dir, file, "not a mapping", "expected")


def test_odometry_without_manifest_section(rec_dir):
    make_odometry(np.arange(1000.0, 1001.0, 0.1), False).save_csv(rec_dir / "odometry.csv")
    load_error(rec_dir, "recording.yaml", "field 'odometry'", "expected {wheel_radius_m, track_m}")


def test_odometry_bad_wheel_radius(rec_dir):
    make_odometry(np.arange(1000.0, 1001.0, 0.1), False).save_csv(rec_dir / "odometry.csv")
    edit_yaml(rec_dir, "recording.yaml", set_key("odometry", {"wheel_radius_m": -0.3, "track_m": 1.6}))
    load_error(rec_dir, "recording.yaml", "field 'odometry.wheel_radius_m'", "value -0.3",
               "expected a positive length in metres")


# --- chunked validation ----------------------------------------------------------------------
BATCH = 1000


@pytest.fixture
def small_batches(monkeypatch):
    monkeypatch.setattr(graphcal.recording.points, "BATCH_ROWS", BATCH)
    return BATCH


def recorded_batch_sizes(monkeypatch) -> list[int]:
    """Spy on PointTable.iter_batches: the sizes of the batches it yields."""
    sizes, original = [], PointTable.iter_batches

    def spy(self, *args, **kwargs):
        for batch in original(self, *args, **kwargs):
            sizes.append(len(next(iter(batch.values()))))
            yield batch

    monkeypatch.setattr(PointTable, "iter_batches", spy)
    return sizes


def test_validation_reads_in_batches(rec_dir, small_batches, monkeypatch):
    sizes = recorded_batch_sizes(monkeypatch)
    n = len(Recording.load(rec_dir).points)
    assert n > 10 * BATCH
    assert sum(sizes) == n and max(sizes) <= BATCH and len(sizes) == math.ceil(n / BATCH)


@pytest.mark.parametrize("boundary", [2 * BATCH, 7 * BATCH])
def test_unsorted_time_across_a_batch_boundary(rec_dir, small_batches, boundary):
    """Rows boundary-1 and boundary swapped: each batch is sorted, only the seam is not."""
    earlier, later = swap_rows(rec_dir, boundary - 1, boundary)
    error = load_error(rec_dir, "points.parquet", "field 'time'", f"at row index {boundary} ",
                       f"time {earlier!r} at row index {boundary} is before {later!r}")
    assert error.field == "time"


@pytest.mark.parametrize("row", [BATCH - 1, BATCH, 5 * BATCH + 17])
def test_bad_value_reports_global_row(rec_dir, small_batches, row):
    rewrite_points(rec_dir, lambda table: set_value(table, "range", row, np.nan))
    load_error(rec_dir, "points.parquet", f"value nan at row index {row} ")


@pytest.mark.parametrize("batch_rows", [777, 999, 1000, 4096, 10**7])
def test_iter_batches_bounded(simulated, valid_dir, batch_rows):
    """File-backed and in-memory tables: batches of at most batch_rows rows, all rows in order."""
    on_disk = PointTable.open(valid_dir / "points.parquet")
    n = len(on_disk)
    expected = simulated.points.read()
    for table in (on_disk, simulated.points):
        batches = list(table.iter_batches(["time", "fibre", "range"], batch_rows=batch_rows))
        assert max(len(b["time"]) for b in batches) <= batch_rows
        assert len(batches) == math.ceil(n / batch_rows)
        for name in ("time", "fibre", "range"):
            np.testing.assert_array_equal(np.concatenate([b[name] for b in batches]), expected[name])


def test_iter_batches_default_follows_batch_rows(valid_dir, small_batches):
    table = PointTable.open(valid_dir / "points.parquet")
    sizes = [len(b["time"]) for b in table.iter_batches(["time"])]
    assert max(sizes) <= BATCH and sum(sizes) == len(table)


# --- atomic save -----------------------------------------------------------------------------
def test_save_replaces_an_existing_recording(rec_dir, simulated):
    """A recording without truth/ saved over one with truth/: nothing of the old one remains."""
    other = Recording(name="other", crs=simulated.crs, sensor=simulated.sensor, extrinsic=simulated.extrinsic,
                      trajectory=simulated.trajectory, points=PointTable.from_arrays(
                          **{k: v[:100] for k, v in simulated.points.read().items()}))
    other.save(rec_dir)
    loaded = Recording.load(rec_dir)
    assert loaded.name == "other" and len(loaded.points) == 100 and loaded.truth is None
    assert not (rec_dir / "truth").exists()
    assert sorted(p.name for p in rec_dir.parent.iterdir()) == ["rec"]


def broken_save(self, path):
    """PointTable.save failing midway through its file."""
    Path(path).write_bytes(b"half a parquet file")
    raise OSError("disk full")


def test_failed_save_keeps_the_previous_recording(rec_dir, simulated, monkeypatch):
    before = file_digest(rec_dir)
    monkeypatch.setattr(PointTable, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_copy(simulated, rec_dir)
    assert file_digest(rec_dir) == before
    assert sorted(p.name for p in rec_dir.parent.iterdir()) == ["rec"], "temporary directory left behind"
    monkeypatch.undo()
    assert_same_recording(simulated, Recording.load(rec_dir))


def test_failed_final_rename_restores_the_previous_recording(rec_dir, simulated, monkeypatch):
    """The last step (temporary directory -> rec) fails after rec was moved aside: rec comes back."""
    before, real_replace = file_digest(rec_dir), os.replace

    def replace(src, dst):
        if Path(dst) == rec_dir and Path(src).name.endswith(".tmp"):
            raise OSError("rename failed")
        return real_replace(src, dst)

    monkeypatch.setattr(graphcal.common.atomic.os, "replace", replace)
    with pytest.raises(OSError, match="rename failed"):
        save_copy(simulated, rec_dir)
    monkeypatch.undo()
    assert file_digest(rec_dir) == before
    assert sorted(p.name for p in rec_dir.parent.iterdir()) == ["rec"]


def test_failed_first_save_leaves_nothing(simulated, tmp_path, monkeypatch):
    monkeypatch.setattr(PointTable, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_copy(simulated, tmp_path / "new")
    assert list(tmp_path.iterdir()) == []


def test_saved_files_follow_the_umask(valid_dir):
    """Temporary files and directories are created private (0600/0700); once saved, a recording
    must carry the usual permissions (0666/0777 minus the umask), like any file the user writes."""
    umask = os.umask(0)
    os.umask(umask)
    for path in [valid_dir, *valid_dir.rglob("*")]:
        expected = (0o777 if path.is_dir() else 0o666) & ~umask
        assert path.stat().st_mode & 0o777 == expected, (path, oct(path.stat().st_mode))


def test_a_batch_of_returns_shares_the_world_trajectory(simulated, monkeypatch):
    import graphcal.recording.directory

    real, calls = graphcal.recording.directory.to_world, []
    monkeypatch.setattr(graphcal.recording.directory, "to_world", lambda *args: calls.append(args) or real(*args))
    recording = dataclasses.replace(simulated)  # its own cache
    world = recording.world
    batch = recording.with_points(PointTable.from_arrays(**recording.points.read(["time", "fibre", "range", "azimuth"])))
    assert batch.world is world and len(calls) == 1
    assert len(batch.points) == len(recording.points) and batch.trajectory is recording.trajectory


@pytest.mark.parametrize(("change", "fragments"), [
    (lambda s: s["fibres"][3].update(elevation_deg=200.0), ("fibres", "row 3", "elevation_deg is 200", "-90..90")),
    (lambda s: s["fibres"][5].update(elevation_deg=s["fibres"][2]["elevation_deg"]),
     ("fibres [2, 5] share the elevation", "one elevation per laser")),
    (lambda s: s.update(rotation_hzz=10.0), ("unknown field(s) ['rotation_hzz']",)),
    (lambda s: s["fibres"][0].update(elevaton_deg=1.0), ("row 0", "unknown field(s) ['elevaton_deg']")),
])
def test_sensor_yaml_that_cannot_be_a_head_is_refused(rec_dir, change, fragments):
    sensor = yaml.safe_load((rec_dir / "sensor.yaml").read_text())
    change(sensor)
    (rec_dir / "sensor.yaml").write_text(yaml.safe_dump(sensor))
    load_error(rec_dir, "sensor.yaml", *fragments)


@pytest.mark.parametrize("column, value, words", [("x", "9e12", "metres within +-1e+08"),
                                                  ("z", "-3e6", "metres within +-100000")])
def test_trajectory_coordinate_no_vehicle_has(rec_dir, column, value, words):
    """A grid coordinate of 9e12 m once reached open3d as 'voxel_size is too small': refused at load."""
    lines = trajectory_lines(rec_dir)
    header = lines[0].split(",")
    cells = lines[12].split(",")
    cells[header.index(column)] = value
    lines[12] = ",".join(cells)
    write_trajectory(rec_dir, lines)
    load_error(rec_dir, "trajectory.csv", f"field '{column}', row 12", words)


def test_take_reads_rows_batch_by_batch_as_indexing_the_whole_column(tmp_path, monkeypatch):
    monkeypatch.setattr(graphcal.recording.points, "BATCH_ROWS", 1000)
    rng = np.random.default_rng(5)
    n = 4500
    table = PointTable.from_arrays(time=np.arange(n) * 1e-4, fibre=rng.integers(0, 32, n), range=rng.random(n),
                                   azimuth=rng.random(n), intensity=rng.random(n))
    table.save(tmp_path / "points.parquet")
    on_disk = PointTable.open(tmp_path / "points.parquet")
    assert on_disk._file.metadata.num_row_groups == 5
    rows = np.sort(rng.choice(n, 700, replace=False))
    whole = on_disk.read(["range", "fibre"])
    taken = on_disk.take(["range", "fibre"], rows)
    np.testing.assert_array_equal(taken["range"], whole["range"][rows])
    np.testing.assert_array_equal(taken["fibre"], whole["fibre"][rows])
    with pytest.raises(ValueError, match="sorted"):
        on_disk.take(["range"], rows[::-1])


@pytest.mark.parametrize("damage", ["truncated", "short"])
def test_a_damaged_truth_is_refused_naming_its_file(tmp_path, damage):
    """truth/points.parquet cut short (a crashed copy) or with fewer rows than points.parquet: evaluation's reads
    refuse it, naming the file, instead of a pyarrow traceback or a silent misalignment."""
    from graphcal.simulation.script import load_scenario_builder

    path = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.005, seed=0), quiet=True).save(tmp_path / "r")
    truth_file = path / "truth" / "points.parquet"
    if damage == "truncated":
        truth_file.write_bytes(truth_file.read_bytes()[:-100])
    else:
        pq.write_table(pq.read_table(truth_file).slice(0, 10), truth_file)
    truth = Recording.load(path).truth
    rows = np.array([0, 5, len(Recording.load(path).points) - 1])
    with pytest.raises(RecordingError, match="truth/points.parquet"):
        truth.world_points_at(rows)
