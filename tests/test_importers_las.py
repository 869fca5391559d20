"""`import las` on LAS/LAZ files the test georeferences from known raw returns with graphcal's forward model
(a 16-laser head with a ring extra dimension; a single-beam line scanner), read in chunks, and on the leeward
airborne sample."""

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from typer.testing import CliRunner

import ring_scans_synth as synth
from graphcal.cli.main import app
from graphcal.common.errors import RecordingError
from graphcal.importers.las_cloud import import_las
from graphcal.importers.velodyne_calibration import read_velodyne_calibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.geodesy import to_world
from graphcal.recording.georeference import georeference
from graphcal.recording.sensor import SensorModel
from graphcal.recording.trajectory import Trajectory

LEEWARD = Path("/work/shared/data/real/leeward_airborne_las_sbet")
CRS = "EPSG:32631"
T0 = 200_000.0  # GPS seconds of week
MOUNT = Extrinsic((0.8, -0.1, 1.9), (0.5, -1.0, 91.0))


def _trajectory() -> Trajectory:
    """A 2 s drive north-east near Paris, turning, 10 poses a second (GPS seconds of week)."""
    t = T0 + np.arange(0.0, 2.01, 0.1)
    position = np.column_stack([48.85 + 1e-6 * (t - T0), 2.35 + 2e-6 * (t - T0), np.full(len(t), 60.0)])
    rpy = np.column_stack([np.full(len(t), 1.0), np.full(len(t), -0.5), 30.0 + 5.0 * (t - T0)])
    return Trajectory(t, position, rpy, geodetic=True)


def _returns(model: SensorModel, n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    fibre = rng.integers(0, model.n_fibres, n)
    return {"time": np.sort(rng.uniform(T0 + 0.3, T0 + 1.7, n)), "fibre": fibre,
            "range": rng.uniform(10.0, 60.0, n), "azimuth": rng.uniform(0.0, 2 * np.pi, n),
            "intensity": rng.integers(0, 4000, n)}


def _write_las(path: Path, world: np.ndarray, truth: dict, ring: np.ndarray | None, crs: str | None, version: str):
    header = laspy.LasHeader(point_format=6 if version == "1.4" else 1, version=version)
    header.scales = [1e-4] * 3
    header.offsets = np.floor(world.min(axis=0))
    if ring is not None:
        header.add_extra_dim(laspy.ExtraBytesParams(name="ring", type=np.uint16))
    if crs is not None:
        header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = world.T
    las.gps_time = truth["time"]
    las.intensity = truth["intensity"]
    if ring is not None:
        las.ring = ring
    las.write(path)


def _azimuth_error(a, b):
    return np.angle(np.exp(1j * (np.asarray(a, dtype=np.float64) - b)))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_with_ring_dimension_gives_back_the_raw_returns(tmp_path, suffix):
    """LAS 1.4 with a WKT CRS and a ring extra dimension (velodyne numbering), the mounting and the driver's
    calibration given: fibre, range, azimuth exact to the LAS coordinate resolution (0.1 mm)."""
    model = synth.sensor(with_offsets=True)
    synth.write_ros_calibration(tmp_path / "calib.yaml", model)
    truth = _returns(model, 3000)
    trajectory = _trajectory()
    world = georeference(truth["time"], truth["fibre"], truth["range"], truth["azimuth"], model, MOUNT,
                         to_world(trajectory, CRS).poses)
    ring = np.argsort(model.fibres_by_elevation())[truth["fibre"]]
    _write_las(tmp_path / f"cloud{suffix}", world, truth, ring, CRS, "1.4")
    recording = import_las(tmp_path / f"cloud{suffix}", trajectory, tmp_path / "rec",
                           lever_arm_m=MOUNT.lever_arm_m, boresight_deg=MOUNT.boresight_deg,
                           calibration=read_velodyne_calibration(tmp_path / "calib.yaml"))
    points = recording.points.read()
    assert recording.crs.startswith("PROJCRS") or recording.crs.startswith("PROJCS")
    np.testing.assert_allclose(points["time"], truth["time"])
    np.testing.assert_array_equal(points["fibre"], truth["fibre"])
    np.testing.assert_allclose(points["range"], truth["range"], atol=5e-4)
    np.testing.assert_allclose(_azimuth_error(points["azimuth"], truth["azimuth"]), 0.0, atol=5e-5)


def test_single_beam_line_scanner_gets_its_scan_plane(tmp_path):
    """No laser field, no mounting given: the scan plane's normal becomes the lidar's z axis; ranges come back,
    azimuths up to one constant turn in the plane. LAS 1.2 without a CRS: --crs, through the command line."""
    flat = SensorModel(model="LINE", rotation_hz=50.0, reference_fibre=0, elevation_deg=np.zeros(1),
                       **{name: np.zeros(1) for name in ("azimuth_offset_deg", "range_offset_m", "vertical_offset_m",
                                                         "horizontal_offset_m", "height_offset_m")})
    truth = _returns(flat, 2000, seed=2)
    truth["azimuth"] = np.radians(180.0 + 40.0 * np.sin(2 * np.pi * 50.0 * (truth["time"] - T0)))  # a swath
    trajectory = _trajectory()
    world = georeference(truth["time"], truth["fibre"], truth["range"], truth["azimuth"], flat, MOUNT,
                         to_world(trajectory, CRS).poses)
    _write_las(tmp_path / "line.las", world, truth, None, None, "1.2")
    trajectory.save_csv(tmp_path / "trajectory.csv")
    result = CliRunner().invoke(app, ["import", "las", str(tmp_path / "line.las"), "--trajectory",
                                      str(tmp_path / "trajectory.csv"), "--lever-arm", "0.8,-0.1,1.9",
                                      "--crs", CRS, "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 0, result.output
    recording = Recording.load(tmp_path / "rec")
    points = recording.points.read()
    np.testing.assert_allclose(points["range"], truth["range"], atol=5e-4)
    turn = _azimuth_error(points["azimuth"], truth["azimuth"])
    np.testing.assert_allclose(turn - np.median(turn), 0.0, atol=5e-5)
    assert any("FITTED" in n and "boresight" in n for n in recording.source["notes"])
    assert any("one beam" in n for n in recording.source["notes"])


def test_las_errors_name_the_file(tmp_path):
    (tmp_path / "junk.las").write_bytes(b"LASF" + b"\0" * 300)
    with pytest.raises(RecordingError, match="junk.las: not a readable LAS"):
        import_las(tmp_path / "junk.las", _trajectory(), tmp_path / "rec")
    truth = _returns(synth.sensor(False), 50)
    world = np.column_stack([np.full(50, 450_000.0), np.full(50, 5_400_000.0), np.zeros(50)])
    _write_las(tmp_path / "nocrs.las", world, truth, None, None, "1.2")
    with pytest.raises(RecordingError, match="nocrs.las, field 'crs': no CRS"):
        import_las(tmp_path / "nocrs.las", _trajectory(), tmp_path / "rec")
    truth["time"] = truth["time"] + 1000.0
    _write_las(tmp_path / "late.las", world, truth, None, CRS, "1.4")
    with pytest.raises(RecordingError, match="late.las, field 'gps_time'"):
        import_las(tmp_path / "late.las", _trajectory(), tmp_path / "rec")


def _jittered_las(path: Path, block: int) -> int:
    """A LAS file of a 16-laser head whose points are shuffled within blocks of `block` points (out of time order
    by up to a block), a tenth of them after the trajectory's end; its number of points."""
    model = synth.sensor(with_offsets=False)
    truth = _returns(model, 3000, seed=3)
    truth["time"][-300:] += 5.0  # after the trajectory: left out
    world = georeference(np.minimum(truth["time"], T0 + 1.9), truth["fibre"], truth["range"], truth["azimuth"], model,
                         MOUNT, to_world(_trajectory(), CRS).poses)
    order = np.concatenate([start + np.random.default_rng(start).permutation(block)
                            for start in range(0, len(world), block)])
    _write_las(path, world[order], {key: values[order] for key, values in truth.items()},
               np.argsort(model.fibres_by_elevation())[truth["fibre"]][order], CRS, "1.4")
    return len(world)


def test_chunked_las_import_writes_the_same_points_as_one_chunk(tmp_path, monkeypatch):
    """Chunks of 128 points (points up to 100 out of time order, row groups of 1000 rows) against the whole file as
    one chunk: the same points.parquet, byte for byte, and the same recording beside it."""
    monkeypatch.setattr("graphcal.recording.points.BATCH_ROWS", 1000)
    n = _jittered_las(tmp_path / "cloud.las", block=100)
    chunked = import_las(tmp_path / "cloud.las", _trajectory(), tmp_path / "chunked", lever_arm_m=MOUNT.lever_arm_m,
                         boresight_deg=MOUNT.boresight_deg, chunk_points=128)
    whole = import_las(tmp_path / "cloud.las", _trajectory(), tmp_path / "whole", lever_arm_m=MOUNT.lever_arm_m,
                       boresight_deg=MOUNT.boresight_deg, chunk_points=n)
    assert (tmp_path / "chunked/points.parquet").read_bytes() == (tmp_path / "whole/points.parquet").read_bytes()
    for name in ("sensor.yaml", "extrinsic.yaml", "recording.yaml"):
        assert (tmp_path / "chunked" / name).read_text() == (tmp_path / "whole" / name).read_text()
    points = chunked.points.read()
    assert len(whole.points.read()["time"]) == len(points["time"]) == 2700 and np.all(np.diff(points["time"]) >= 0)
    assert chunked.points._file.metadata.num_row_groups == 3
    assert any("300 points outside" in n for n in chunked.source["notes"])


def test_las_out_of_time_order_beyond_a_chunk_is_refused(tmp_path):
    """Points out of time order by up to 100 points, read 30 at a time: refused, naming the file and the field, and
    saying how to sort it; no folder is left behind."""
    _jittered_las(tmp_path / "cloud.las", block=100)
    with pytest.raises(RecordingError, match=r"cloud.las, field 'time': .*time order to within 30 points.*lassort"):
        import_las(tmp_path / "cloud.las", _trajectory(), tmp_path / "rec", lever_arm_m=MOUNT.lever_arm_m,
                   boresight_deg=MOUNT.boresight_deg, chunk_points=30)
    assert not (tmp_path / "rec").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["cloud.las"]


@pytest.mark.skipif(not LEEWARD.is_dir(), reason="leeward sample not present")
def test_leeward_airborne_sample_imports(tmp_path):
    """1325 returns of an airborne line scanner (UTM 11N in GeoTIFF keys), its SBET: raw values that georeference
    back onto the LAS points to within the scan plane's fit."""
    result = CliRunner().invoke(app, ["import", "las", str(LEEWARD / "points.las"), "--trajectory",
                                      str(LEEWARD / "sbet.out"), "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 0, result.output
    recording = Recording.load(tmp_path / "rec")
    summary = recording.validate()
    assert summary.n_points == 1325 and recording.crs == "EPSG:32611" and recording.sensor.n_fibres == 1
    points = recording.points.read()
    assert 4400 < points["range"].min() and points["range"].max() < 5400  # flying about 4.5 km above the ground
    world = georeference(points["time"], points["fibre"], points["range"], points["azimuth"], recording.sensor,
                         recording.extrinsic, recording.world.poses)
    las = laspy.read(LEEWARD / "points.las")
    original = np.column_stack([las.x, las.y, las.z])[np.argsort(las.gps_time, kind="stable")]
    assert np.median(np.linalg.norm(world - original, axis=1)) < 0.3
