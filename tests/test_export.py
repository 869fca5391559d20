"""graphcal export: the Velodyne db.xml and ROS YAML writers against the real files (read back unchanged) and
against the velodyne_pointcloud driver's own decoding (rawdata.cc, written out below as independent math); the
command on a run folder, with its refusals."""

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import graphcal
from graphcal.cli.main import app
from graphcal.exporters import WRITERS, read_original
from graphcal.exporters.velodyne_calibration import write_db_xml, write_ros_yaml
from graphcal.importers.velodyne_calibration import read_velodyne_calibration
from graphcal.recording.sensor import CATALOG

FOLDER = Path(__file__).resolve().parents[2] / "shared/data/real/ros_velodyne_calibrations"
FILES = sorted(FOLDER.rglob("*.xml")) + sorted(FOLDER.rglob("*.yaml")) if FOLDER.is_dir() else []
needs_real = pytest.mark.skipif(not FILES, reason="shared real data absent")
GEOMETRY = ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m", "horizontal_offset_m")


def _format(path: Path) -> str:
    return "velodyne-xml" if path.suffix == ".xml" else "ros-yaml"


# --- velodyne_pointcloud's decoding, from its sources (rawdata.cc RawData::unpack, gen_calibration.py) -----
def _lasers_of_yaml(path: Path) -> dict[int, dict]:
    return {row["laser_id"]: row for row in yaml.safe_load(path.read_text())["lasers"]}


def _lasers_of_db_xml(path: Path) -> dict[int, dict]:
    """gen_calibration.py: cm -> m, degrees -> radians; two-point correction when X and Y are both nonzero."""
    lasers = {}
    for px in ET.parse(path).getroot().iter("px"):
        values = {child.tag: float(child.text) for child in px}
        row = {"rot_correction": math.radians(values["rotCorrection_"]),
               "vert_correction": math.radians(values["vertCorrection_"])}
        for tag, key in (("distCorrection_", "dist_correction"), ("distCorrectionX_", "dist_correction_x"),
                         ("distCorrectionY_", "dist_correction_y"), ("vertOffsetCorrection_", "vert_offset_correction"),
                         ("horizOffsetCorrection_", "horiz_offset_correction")):
            row[key] = values.get(tag, 0.0) * 0.01
        row["two_pt_correction_available"] = bool(row["dist_correction_x"] and row["dist_correction_y"])
        lasers[int(values["id_"])] = row
    return lasers


def _driver_xyz(lasers: dict[int, dict], laser, raw_m, rotation_rad) -> np.ndarray:
    """RawData::unpack for each return: laser id, raw distance [m] (count x distance_resolution) and the
    packet's rotation [rad]; the point in ROS axes (x_coord = y, y_coord = -x)."""
    def column(key, default=0.0):
        return np.array([float(lasers[i].get(key, default)) for i in laser])

    distance = raw_m + column("dist_correction")
    rot, vert = column("rot_correction"), column("vert_correction")
    cos_vert, sin_vert = np.cos(vert), np.sin(vert)
    cos_rot_angle = np.cos(rotation_rad) * np.cos(rot) + np.sin(rotation_rad) * np.sin(rot)
    sin_rot_angle = np.sin(rotation_rad) * np.cos(rot) - np.cos(rotation_rad) * np.sin(rot)
    horiz, vert_offset = column("horiz_offset_correction"), column("vert_offset_correction")
    xy_distance = distance * cos_vert - vert_offset * sin_vert
    xx = np.abs(xy_distance * sin_rot_angle - horiz * cos_rot_angle)
    yy = np.abs(xy_distance * cos_rot_angle + horiz * sin_rot_angle)
    two_point = column("two_pt_correction_available", False).astype(bool)
    dist, dist_x, dist_y = column("dist_correction"), column("dist_correction_x"), column("dist_correction_y")
    corr_x = np.where(two_point, (dist - dist_x) * (xx - 2.4) / (25.04 - 2.4) + dist_x - dist, 0.0)
    corr_y = np.where(two_point, (dist - dist_y) * (yy - 1.93) / (25.04 - 1.93) + dist_y - dist, 0.0)
    x = ((distance + corr_x) * cos_vert - vert_offset * sin_vert) * sin_rot_angle - horiz * cos_rot_angle
    distance_y = distance + corr_y
    y = (distance_y * cos_vert - vert_offset * sin_vert) * cos_rot_angle + horiz * sin_rot_angle
    z = distance_y * sin_vert + vert_offset * cos_vert
    return np.column_stack([y, -x, z])


def _decode(path: Path, laser, raw_m, rotation_rad) -> np.ndarray:
    lasers = _lasers_of_db_xml(path) if path.suffix == ".xml" else _lasers_of_yaml(path)
    return _driver_xyz(lasers, laser, raw_m, rotation_rad)


def _returns(n_fibres: int, count: int = 4000, seed: int = 0, farthest_m: float = 100.0):
    rng = np.random.default_rng(seed)
    return rng.integers(0, n_fibres, count), rng.uniform(1.0, farthest_m, count), rng.uniform(0, 2 * np.pi, count)


def _offsets(n_fibres: int, seed: int = 1) -> np.ndarray:
    """Calibration-sized offsets (m, rad, rad, m): cm of range and height, tenths of a degree."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.normal(0, 0.02, n_fibres), np.radians(rng.normal(0, 0.2, n_fibres)),
                            np.radians(rng.normal(0, 0.1, n_fibres)), rng.normal(0, 0.03, n_fibres)])


# --- (a) the real files read and written back ----------------------------------------------------------
@needs_real
@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_each_real_file_written_back_with_zero_corrections_is_the_original(path, tmp_path):
    sensor = read_velodyne_calibration(path).sensor
    original, notes = read_original(_format(path), path, sensor)
    assert notes == []
    zero = np.zeros((sensor.n_fibres, 4))
    edited = tmp_path / f"edited{path.suffix}"
    assert WRITERS[_format(path)](edited, sensor, zero, original) == []
    assert edited.read_bytes() == path.read_bytes()  # every field, its digits, order, DOCTYPE, comments, line ends
    fresh = tmp_path / f"fresh{path.suffix}"
    WRITERS[_format(path)](fresh, sensor, zero, None)
    again = read_velodyne_calibration(fresh, model=sensor.model).sensor
    for name in GEOMETRY:  # a complete file of the same model: within the format's digits
        np.testing.assert_allclose(getattr(again, name), getattr(sensor, name), rtol=1e-7, atol=1e-12, err_msg=name)


# --- (b) the driver decodes the calibrated model's points ------------------------------------------------
@pytest.mark.parametrize("writer, suffix", [(write_db_xml, ".xml"), (write_ros_yaml, ".yaml")])
@pytest.mark.parametrize("model", ["HDL-64E", "HDL-32E"])
def test_the_driver_decodes_the_calibrated_model(writer, suffix, model, tmp_path):
    sensor = CATALOG[model]
    offsets = _offsets(sensor.n_fibres)
    path = tmp_path / f"calibrated{suffix}"
    notes = writer(path, sensor, offsets)
    assert any("no per-laser height" in note for note in notes)
    laser, raw_m, rotation = _returns(sensor.n_fibres)
    expected = sensor.to_xyz(laser, raw_m, rotation, offsets)  # eq. 4.2 with the offsets
    np.testing.assert_allclose(_decode(path, laser, raw_m, rotation), expected, rtol=0, atol=1e-3)
    # without the offsets the points are off by centimetres: the test sees them
    assert np.abs(_decode(path, laser, raw_m, rotation) - sensor.to_xyz(laser, raw_m, rotation)).max() > 0.05


@needs_real
@pytest.mark.parametrize("name", ["64e_s2.1-sztaki.xml", "64e_s3-xiesc.yaml", "VLP16db.yaml"])
def test_a_real_file_with_offsets_decodes_as_the_model_moves(name, tmp_path):
    """From the unit's own file (two-point corrections, intensity terms): the driver's points move by as much
    as graphcal's model moves with the offsets, and only the calibrated fields changed. Within the two-point
    correction's span (25 m): it varies with |x| and |y|, which a rotated beam changes (1 mm per 0.3 m beyond)."""
    path = next(p for p in FILES if p.name == name)
    sensor = read_velodyne_calibration(path).sensor
    offsets = _offsets(sensor.n_fibres, seed=2)
    original, _ = read_original(_format(path), path, sensor)
    out = tmp_path / f"calibrated{path.suffix}"
    notes = WRITERS[_format(path)](out, sensor, offsets, original)
    laser, raw_m, rotation = _returns(sensor.n_fibres, seed=3, farthest_m=25.0)
    moved = _decode(out, laser, raw_m, rotation) - _decode(path, laser, raw_m, rotation)
    expected = sensor.to_xyz(laser, raw_m, rotation, offsets) - sensor.to_xyz(laser, raw_m, rotation)
    np.testing.assert_allclose(moved, expected, rtol=0, atol=1e-3)
    before, after = (_lasers_of_db_xml(p) if p.suffix == ".xml" else _lasers_of_yaml(p) for p in (path, out))
    changed = {key for i in before for key in before[i] if before[i][key] != after[i][key]}
    calibrated = {"vert_correction", "rot_correction", "dist_correction", "vert_offset_correction"}
    two_point = {"dist_correction_x", "dist_correction_y"}
    assert calibrated <= changed <= calibrated | two_point
    if any(row.get("two_pt_correction_available") for row in before.values()):
        assert two_point <= changed and any("two-point" in note for note in notes)
        for i in before:  # the two-point shape is kept: X - dist and Y - dist as they were
            for key in two_point:
                assert after[i][key] - after[i]["dist_correction"] == pytest.approx(
                    before[i][key] - before[i]["dist_correction"], abs=1e-6)


# --- (c) the command on a run folder ------------------------------------------------------------------
def _write_run(run: Path, recording: Path, sensor, offsets: np.ndarray, held=(), unobservable=(), imprecise=()) -> Path:
    """A calibration run folder written directly: calibration.yaml with these offsets (h_z null for the
    fibres in held), the names unobservable and imprecise, and run.yaml naming the recording."""
    rows = [{"fibre": fibre, "d_range_m": float(d_range), "d_azimuth_deg": math.degrees(d_azimuth),
             "d_elevation_deg": math.degrees(d_elevation), "h_z_m": None if fibre in held else float(h_z),
             "sigma": None} for fibre, (d_range, d_azimuth, d_elevation, h_z) in enumerate(offsets)]
    run.mkdir()
    (run / "calibration.yaml").write_text(yaml.safe_dump({
        "format": "graphcal-calibration/1", "sensor": {"model": sensor.model, "reference_fibre": sensor.reference_fibre},
        "intrinsics": rows, "extrinsic": {"lever_arm_m": [0.8, 0.0, 1.9], "boresight_deg": [0.0, 0.0, 90.0]},
        "trajectory_corrections": [], "effects": [], "unobservable": list(unobservable),
        "imprecise": {name: "imprecise: determined to ..." for name in imprecise}}))
    (run / "run.yaml").write_text(yaml.safe_dump({"format": "graphcal-run/1", "recording": str(recording.resolve())}))
    return run


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A simulated HDL-32E recording and a calibration run folder of it: known offsets, fibre 3's h_z held
    (null), fibre 5's d_range named unobservable and fibre 7's elevation imprecise (fitted: exported as it is)."""
    from graphcal.simulation.script import load_scenario_builder

    root = tmp_path_factory.mktemp("export")
    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.002, seed=3), quiet=True)
    rec = recording.save(root / "rec")
    sensor = recording.sensor
    offsets = _offsets(sensor.n_fibres, seed=5)
    offsets[sensor.reference_fibre] = 0.0
    run = _write_run(root / "run", rec, sensor, offsets, held=(3,), imprecise=("fibre_7.d_elevation_deg",),
                     unobservable=("fibre_3.h_z_m", "fibre_5.d_range_m"))
    expected = offsets.copy()
    expected[3, 3] = expected[5, 0] = 0.0  # held and unobservable: nominal; fibre 7's elevation as fitted
    return run, sensor, expected


def _export(*args):
    return CliRunner().invoke(app, ["export", *map(str, args)])


@pytest.mark.parametrize("export_format, suffix", [("velodyne-xml", ".xml"), ("ros-yaml", ".yaml")])
def test_export_command_writes_the_calibrated_model(run_folder, export_format, suffix, tmp_path):
    run, sensor, offsets = run_folder
    out = tmp_path / f"calibrated{suffix}"
    result = _export(run, "--format", export_format, "--out", out)
    assert result.exit_code == 0, result.output
    assert "fibre_3.h_z_m, fibre_5.d_range_m" in result.output and "nominal" in result.output
    assert f"wrote {out}" in result.output
    laser, raw_m, rotation = _returns(sensor.n_fibres, seed=6)
    np.testing.assert_allclose(_decode(out, laser, raw_m, rotation), sensor.to_xyz(laser, raw_m, rotation, offsets),
                               rtol=0, atol=1e-3)
    assert not list(tmp_path.glob(".*.tmp"))


@needs_real
def test_export_command_from_the_units_file(run_folder, tmp_path):
    """The recording's HDL-32E nominal model is 32db.yaml's: only the calibrated fields of its text change."""
    run, sensor, offsets = run_folder
    original = next(p for p in FILES if p.name == "32db.yaml")
    out = tmp_path / "32db-calibrated.yaml"
    result = _export(run, "--format", "ros-yaml", "--from", original, "--out", out, "-q")
    assert result.exit_code == 0 and result.output == ""
    assert out.read_text().splitlines()[0] == original.read_text().splitlines()[0]  # its comment kept
    laser, raw_m, rotation = _returns(sensor.n_fibres, seed=7)
    np.testing.assert_allclose(_decode(out, laser, raw_m, rotation), sensor.to_xyz(laser, raw_m, rotation, offsets),
                               rtol=0, atol=1e-3)
    # its db.xml (CRLF line ends, 64 slots, 32 enabled): the same lines, only the calibrated tags' numbers changed
    original = next(p for p in FILES if p.name == "32db.xml")
    out = tmp_path / "32db-calibrated.xml"
    result = _export(run, "--format", "velodyne-xml", "--from", original, "--out", out)
    assert result.exit_code == 0 and "two-point" not in result.output  # 32db.xml's X and Y are unused (zero)
    before, after = original.read_bytes().split(b"\r\n"), out.read_bytes().split(b"\r\n")
    assert len(before) == len(after) and after[1] == b"<!DOCTYPE boost_serialization>"
    changed = {re.match(rb"\s*<(\w+)>", line).group(1) for line, old in zip(after, before) if line != old}
    assert changed == {b"vertCorrection_", b"rotCorrection_", b"distCorrection_", b"vertOffsetCorrection_"}
    np.testing.assert_allclose(_decode(out, laser, raw_m, rotation), sensor.to_xyz(laser, raw_m, rotation, offsets),
                               rtol=0, atol=1e-3)


def _refusal(result, *words):
    assert result.exit_code == 2, result.output
    line = result.output.strip()
    assert "\n" not in line and "Traceback" not in line, line
    for word in words:
        assert word in line, line


def test_export_refusals(run_folder, tmp_path):
    run, sensor, _ = run_folder
    out = tmp_path / "out.xml"
    empty = tmp_path / "empty"
    empty.mkdir()
    _refusal(_export(empty, "--format", "velodyne-xml", "--out", out), "calibration.yaml", "not found")
    _refusal(_export(run, "--format", "velodyne-csv", "--out", out), "--format", "velodyne-csv", "ouster-json")
    out.write_text("taken")
    _refusal(_export(run, "--format", "velodyne-xml", "--out", out), "--out", "already exists")
    assert out.read_text() == "taken"


@needs_real
@pytest.mark.parametrize("name, words", [("VLP16db.yaml", ("16 lasers", "32 fibres")),
                                         ("64e_utexas.yaml", ("64 lasers",)),
                                         ("VeloView-VLP-32C.yaml", ("elevation", "another model")),
                                         ("32db.xml", ("--from", ".yaml"))])
def test_export_refuses_another_models_file(run_folder, name, words, tmp_path):
    run, _, _ = run_folder
    original = next(p for p in FILES if p.name == name)
    out = tmp_path / "out.yaml"
    _refusal(_export(run, "--format", "ros-yaml", "--from", original, "--out", out), str(original), *words)
    assert not out.exists()


OUSTER = FOLDER.parent / "ouster_sdk_pcaps"
OUSTER_FILES = sorted(OUSTER.glob("*.json")) if OUSTER.is_dir() else []


@pytest.mark.skipif(len(OUSTER_FILES) < 2, reason="shared real Ouster metadata absent")
def test_export_command_ouster_json(run_folder, tmp_path):
    """The same command writes Ouster metadata through write_ouster_json: only the beam angles change; another
    unit's product line is refused."""
    import json
    import shutil

    from graphcal.importers.ouster_metadata import read_ouster_metadata

    run, _, _ = run_folder
    original = OUSTER_FILES[-1]
    sensor = read_ouster_metadata(original).sensor_model()
    rec = tmp_path / "rec"
    shutil.copytree(yaml.safe_load((run / "run.yaml").read_text())["recording"], rec)
    (rec / "sensor.yaml").write_text(yaml.safe_dump(sensor.to_dict(), sort_keys=False))
    offsets = _offsets(sensor.n_fibres, seed=8)
    ouster_run = _write_run(tmp_path / "run", rec, sensor, offsets)
    out = tmp_path / "calibrated.json"
    result = _export(ouster_run, "--format", "ouster-json", "--from", original, "--out", out)
    assert result.exit_code == 0, result.output
    assert "d_range_m left out" in result.output and "h_z_m left out" in result.output
    before, after = json.loads(original.read_text()), json.loads(out.read_text())
    assert {name for name in before if before[name] != after[name]} == {"beam_altitude_angles", "beam_azimuth_angles"}
    np.testing.assert_allclose(after["beam_azimuth_angles"], sensor.azimuth_offset_deg + np.degrees(offsets[:, 1]),
                               atol=1e-6)
    _refusal(_export(ouster_run, "--format", "ouster-json", "--from", OUSTER_FILES[0], "--out", tmp_path / "o.json"),
             str(OUSTER_FILES[0]), "prod_line")
    _refusal(_export(ouster_run, "--format", "velodyne-xml", "--out", tmp_path / "o.xml"), "beam origin")


@needs_real
@pytest.mark.parametrize("name", ["64e_utexas.yaml", "VLS128.yaml"])
def test_a_field_the_original_lacks_is_added_to_each_laser(name, tmp_path):
    """64e_utexas.yaml (block style) and VLS128.yaml (flow style) have no horiz_offset_correction: a nominal
    model with horizontal offsets adds it to each laser's entry, the rest of the text as it was."""
    from dataclasses import replace

    path = next(p for p in FILES if p.name == name)
    sensor = read_velodyne_calibration(path).sensor
    horizontal = np.where(np.arange(sensor.n_fibres) % 2 == 0, 0.026, -0.026)
    shifted = replace(sensor, horizontal_offset_m=horizontal)
    out = tmp_path / name
    write_ros_yaml(out, shifted, np.zeros((sensor.n_fibres, 4)), path.read_text())
    lasers = _lasers_of_yaml(out)
    np.testing.assert_array_equal([lasers[i]["horiz_offset_correction"] for i in range(sensor.n_fibres)], horizontal)
    added = r"(, |\n[ \t]*)horiz_offset_correction: -?[0-9.]+"  # in a flow mapping / as a block mapping's line
    assert re.sub(added, "", out.read_text()) == path.read_text()
    laser, raw_m, rotation = _returns(sensor.n_fibres, seed=9, farthest_m=25.0)  # utexas: two-point in use
    moved = _decode(out, laser, raw_m, rotation) - _decode(path, laser, raw_m, rotation)
    np.testing.assert_allclose(moved, shifted.to_xyz(laser, raw_m, rotation) - sensor.to_xyz(laser, raw_m, rotation),
                               rtol=0, atol=1e-3)


@needs_real
def test_export_refuses_an_original_it_cannot_edit_in_place(run_folder, tmp_path):
    """32db.yaml rewritten with its lasers as one flow list: readable, but not editable field by field."""
    run, _, _ = run_folder
    lasers = yaml.safe_load(next(p for p in FILES if p.name == "32db.yaml").read_text())["lasers"]
    original = tmp_path / "flow.yaml"
    original.write_text(yaml.safe_dump({"lasers": lasers}, default_flow_style=True))
    out = tmp_path / "out.yaml"
    _refusal(_export(run, "--format", "ros-yaml", "--from", original, "--out", out), str(original), "block list")
    assert not out.exists()


def _ros_yaml_of_db_xml(path: Path, out: Path) -> Path:
    """The ROS YAML that velodyne_pointcloud's gen_calibration.py makes of a db.xml (_lasers_of_db_xml)."""
    lasers = [{"laser_id": laser_id, **row} for laser_id, row in sorted(_lasers_of_db_xml(path).items())]
    out.write_text(yaml.safe_dump({"lasers": lasers, "num_lasers": len(lasers), "distance_resolution": 0.002}))
    return out


@pytest.mark.parametrize("writer, suffix", [(write_db_xml, ".xml"), (write_ros_yaml, ".yaml")])
def test_velodyne_decoder_decodes_the_exported_model_within_a_millimetre(writer, suffix, tmp_path):
    """A calibrated HDL-32E written back (db.xml through gen_calibration.py's conversion, or the ROS YAML) and a
    capture of known raw values decoded by velodyne-decoder 3.1 with it: every point within 1 mm of graphcal's
    calibrated model on the same raw values (the decoder rounds each azimuth to 0.01 deg, and puts the vertical
    offset straight up: decoder_minus_model, with the exported file's offsets)."""
    import velodyne_decoder as vd
    from scipy.spatial import cKDTree
    from velodyne_reference import decoder_minus_model
    from velodyne_synth import spinning_capture

    from graphcal.importers.velodyne_pcap import decode_pcap

    sensor, offsets = CATALOG["HDL-32E"], _offsets(32)
    path = tmp_path / f"calibrated{suffix}"
    writer(path, sensor, offsets)
    readable = path if suffix == ".yaml" else _ros_yaml_of_db_xml(path, tmp_path / "converted.yaml")
    exported = read_velodyne_calibration(readable).sensor
    pcap = tmp_path / "capture.pcap"
    pcap.write_bytes(spinning_capture(n_packets=40, seed=3, packet_us=552.96, block_step=19.9).pcap)
    returns = decode_pcap(pcap, quiet=True).returns
    fibre, range_m = returns["fibre"].astype(int), returns["range"].astype(np.float64)
    config = vd.Config()
    config.model, config.calibration = vd.Model.HDL32E, vd.Calibration.read(str(readable))
    config.min_range, config.max_range = 0.0, 1000.0
    reference = np.concatenate([scan.points for scan in vd.read_pcap(str(pcap), config)])[:, :3]
    assert len(reference) == len(range_m)
    tree = cKDTree(reference)
    error = np.full(len(range_m), np.inf)
    for rounding in (np.floor, np.ceil):
        azimuth = np.radians(np.mod(rounding(np.degrees(returns["azimuth"].astype(np.float64)) * 100), 36000) / 100)
        xyz = sensor.to_xyz(fibre, range_m, azimuth, offsets) + decoder_minus_model(exported, fibre, azimuth)
        error = np.minimum(error, tree.query(xyz)[0])
    assert error.max() < 1e-3, error.max()
    # the nominal model is centimetres away: the comparison sees the calibration
    assert np.median(tree.query(sensor.to_xyz(fibre, range_m, returns["azimuth"].astype(np.float64)))[0]) > 5e-3
