"""Run folders of the command line: calibrate (results, run.rrd read back with rerun's own reader,
report.html), evaluate, apply (LAS/LAZ/PLY), report, view, deskew's run.rrd.

One small calibration (sim6_turn at size 0.02, 3 outer iterations) is shared by the module."""

import base64
import csv
import math
import re
import shutil

import laspy
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from rerun.chunk import RrdReader
from rrd_read import chunks as _chunks
from rrd_read import column as _column
from typer.testing import CliRunner

import graphcal
from graphcal.calibration.before_after import BeforeAfter
from graphcal.calibration.evaluate import nominal_calibration
from graphcal.cli.main import app
from graphcal.clouds.formats import las_writer
from graphcal.calibration.corrected_cloud import write_corrected_cloud
from graphcal.common.errors import ConfigError
from graphcal.recording.directory import Recording
from graphcal.simulation.script import load_scenario_builder

SIM6 = load_scenario_builder("sim6_turn")
VIEWER_POINTS = 5000


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    recording = graphcal.simulate(SIM6(size=0.02, seed=1), quiet=True).save(root / "rec")
    settings = root / "settings.yaml"
    # the coarse phase on a subsample: the residuals "before" must be its first iteration's pairs still
    settings.write_text("max_points: 20000\nstopping: {max_outer_iterations: 3, refuse_unconverged: false}\n"
                        "association: {coarse: {max_points: 10000}}\n")
    result = CliRunner().invoke(app, ["calibrate", str(recording), "--mode", "trajectory", "--config", str(settings),
                                      "--out", str(root / "run"), "--viewer-points", str(VIEWER_POINTS), "-q"])
    assert result.exit_code == 0, result.output
    return recording, root / "run"


def _history(folder):
    with (folder / "history.csv").open(newline="") as stream:
        return list(csv.DictReader(stream))


def test_calibrate_writes_a_complete_run_folder(calibrated):
    recording, folder = calibrated
    for name in ("calibration.yaml", "config.yaml", "history.csv", "residuals.parquet", "pairs_nominal.parquet",
                 "pairs_calibrated.parquet",
                 "evaluation.yaml", "run.rrd", "report.html", "run.yaml"):
        assert (folder / name).is_file(), name
    manifest = yaml.safe_load((folder / "run.yaml").read_text())
    assert manifest["format"] == "graphcal-run/1" and manifest["recording"] == str(recording.resolve())
    config = yaml.safe_load((folder / "config.yaml").read_text())  # resolved for the recording: noise-free sim6
    weighting = config["weighting"]
    assert 0 <= weighting["range_noise_m"] < 1e-3 and weighting["pair_noise"] == "uniform"
    assert config["features"]["voxel_m"] == 0
    stages = manifest["timings_s"]
    for stage in ("load and validate the recording", "calibrate: prepare", "calibrate: solve trajectory (coarse)",
                  "calibrate: weak directions at the start", "calibrate: weak directions, fine phase",
                  "calibrate: final fit and marginals", "residuals before/after",
                  "evaluate against truth", "viewer file", "report"):
        assert stages[stage] >= 0.0, stage
    # the fine phase, with what the probe named held (label) or not
    assert [name for name in stages if name.startswith("calibrate: solve trajectory") and name.endswith("(fine)")]
    assert not list(folder.glob(".*.tmp")), "a temporary file was left behind"


def test_rrd_holds_the_run_read_back_with_rerun(calibrated):
    recording, folder = calibrated
    reader = RrdReader(folder / "run.rrd")
    assert len(reader.blueprints()) == 1  # the layout travels with the file
    paths = set(reader.store().schema().entity_paths())
    expected = {"/summary", "/parameters/table", "/residuals/before", "/residuals/after",
                "/world/trajectory/before", "/world/trajectory/after", "/world/trajectory/truth",
                "/world/trajectory/corrections", "/metrics/weight_sum", "/metrics/J_cm2/before_solve",
                "/metrics/log10_J_cm2/after_solve", "/parameters/corrections/x_cm/estimate",
                "/parameters/corrections/z_cm/plus_1sigma"}
    expected |= {f"/world/cloud/{which}/by_{colour}" for which in ("before", "after")
                 for colour in ("fibre", "time", "residual")}
    assert expected <= paths, expected - paths
    chunks = _chunks(folder / "run.rrd")
    history = _history(folder)
    J = [v[0] for v in _column(chunks["/metrics/J_cm2/before_solve"], "Scalars:scalars")]
    np.testing.assert_allclose(J, [float(row["energy_cm2"]) for row in history], rtol=1e-12)
    assert _column(chunks["/metrics/J_cm2/before_solve"], "iteration") == list(range(len(history)))
    # the clouds: VIEWER_POINTS returns each, coloured by fibre through class ids
    (fibre,) = _column(chunks["/world/cloud/after/by_fibre"], "Points3D:class_ids")
    (positions,) = _column(chunks["/world/cloud/after/by_fibre"], "Points3D:positions")
    assert len(fibre) == len(positions) == VIEWER_POINTS and max(fibre) < recording_fibres(recording)
    # positions are relative to a local origin (float32): the INS trajectory minus a whole-metre offset
    ((strip,),) = _column(chunks["/world/trajectory/before"], "LineStrips3D:strips")
    poses = Recording.load(recording, validate=False).world.poses.position_m
    offset = poses[: len(strip)] - np.array(strip, dtype=np.float64)
    np.testing.assert_allclose(offset - offset[0], 0.0, atol=1e-3)
    np.testing.assert_allclose(offset[0], np.round(offset[0]), atol=1e-3)
    assert np.abs(np.array(positions)).max() < 200.0
    # the residual colouring shows returns paired in each cloud, at their p (at most VIEWER_POINTS of them)
    from scipy.spatial import cKDTree

    residuals = BeforeAfter.load(folder)
    for which in ("before", "after"):
        (points,) = _column(chunks[f"/world/cloud/{which}/by_residual"], "Points3D:positions")
        p_m = getattr(residuals, which).p_m
        assert len(points) == min(len(p_m), VIEWER_POINTS)
        distance, _ = cKDTree(p_m).query(np.array(points) + offset[0])
        assert distance.max() < 2e-3
    ((summary,),) = _column(chunks["/summary"], "TextDocument:text")
    assert "trajectory.common_translation" in summary and "local origin" in summary


def recording_fibres(path):
    return Recording.load(path, validate=False).sensor.n_fibres


def test_residuals_before_are_the_first_iteration_and_shrink_after(calibrated):
    """In the nominal cloud the pairs are the first outer iteration's: their J and weight sum are
    the history's first; paired again the same way in the calibrated cloud, J is much lower."""
    recording, folder = calibrated
    residuals = BeforeAfter.load(folder)
    first = _history(folder)[0]
    assert len(residuals.before.row_p) == int(first["pairs"])
    assert residuals.before.energy_cm2() == pytest.approx(float(first["energy_cm2"]), rel=1e-5)
    assert float(residuals.before.weight.sum()) == pytest.approx(float(first["weight_sum"]), rel=1e-5)
    assert residuals.after.energy_cm2() < 0.2 * residuals.before.energy_cm2()
    # the residual is n.(p - m) with p and m where the calibration puts them (independent: apply_calibration)
    rec = Recording.load(recording, validate=False)
    world = graphcal.apply_calibration(graphcal.Calibration.load(folder, rec.sensor), rec)
    after = residuals.after
    np.testing.assert_allclose(world[after.row_p], after.p_m, atol=1e-6)
    distance = np.linalg.norm(world[after.row_p] - world[after.row_m], axis=1)
    assert np.all(np.abs(after.residual_m) <= distance + 1e-6)


def test_report_is_self_contained_and_complete(calibrated):
    _, folder = calibrated
    page = (folder / "report.html").read_text()
    assert not re.search(r"(src|href)=['\"](?!data:)", page), "the report links to something outside itself"
    # it names the run folder, not the working folder the run was written in before it was moved into place
    assert f"<title>graphcal report: {folder.name}</title>" in page and ".partial" not in page
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", page)
    assert len(images) == 5  # J curve, residuals, the cloud before/after, corrections, timings
    for image in images:
        assert base64.b64decode(image)[:8] == b"\x89PNG\r\n\x1a\n"
    for text in ("Energy J per outer iteration", "Residuals before and after", "The cloud before and after",
                 "Errors against truth",
                 "c2c mean", "Trajectory corrections per control time", "trajectory.common_translation",
                 "Time per stage", "calibrate: solve trajectory",
                 "imprecise (fitted, 1-sigma above the accuracy required)"):
        assert text in page, text
    evaluation = yaml.safe_load((folder / "evaluation.yaml").read_text())
    assert f"{evaluation['cloud_to_cloud_m']['before']['mean'] * 100:12.3g}".strip() in page


def test_report_command_rewrites_the_report_and_rejects_other_folders(calibrated, tmp_path):
    _, folder = calibrated
    copy = shutil.copytree(folder, tmp_path / "copy")
    (copy / "report.html").unlink()
    result = CliRunner().invoke(app, ["report", str(copy)])
    assert result.exit_code == 0 and (copy / "report.html").is_file(), result.output
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and "no calibration.yaml" in result.output
    history = (copy / "history.csv").read_text()
    (copy / "history.csv").write_text(history.replace("energy_cm2", "J", 1))
    result = CliRunner().invoke(app, ["report", str(copy)])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert "history.csv" in result.output and "field 'energy_cm2'" in result.output
    (copy / "history.csv").write_text(history)
    calibration = yaml.safe_load((copy / "calibration.yaml").read_text())
    del calibration["sensor"]["reference_fibre"]
    (copy / "calibration.yaml").write_text(yaml.safe_dump(calibration))
    result = CliRunner().invoke(app, ["report", str(copy)])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert "calibration.yaml" in result.output and "field 'sensor.reference_fibre'" in result.output
    for change, command, words in (
            (lambda c: c.update(unobservable=5), ["report", str(copy)], "field 'unobservable'"),
            (lambda c: c["intrinsics"][2].update(d_elevation_deg=1e6),
             ["apply", str(copy), str(calibrated[0]), "--out", str(tmp_path / "cloud.laz")],
             "intrinsics[2].d_elevation_deg"),
            (lambda c: c.update(effects=[{"effect": "quantum_foam", "magnitude": 1.0}]), ["report", str(copy)],
             "effects[0].effect"),
            (lambda c: [row.update(time=row["time"] + 1e5) for row in c["trajectory_corrections"]],
             ["apply", str(copy), str(calibrated[0]), "--out", str(tmp_path / "cloud.laz")],
             "trajectory corrections apply only to the drive they were made on")):
        tampered = yaml.safe_load((folder / "calibration.yaml").read_text())
        change(tampered)
        (copy / "calibration.yaml").write_text(yaml.safe_dump(tampered))
        result = CliRunner().invoke(app, command)
        assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
        assert words in result.output and not (tmp_path / "cloud.laz").exists()


def test_evaluate_command_matches_the_run_and_needs_truth(calibrated, tmp_path):
    recording, folder = calibrated
    copy = shutil.copytree(folder, tmp_path / "copy")
    (copy / "evaluation.yaml").unlink()
    result = CliRunner().invoke(app, ["evaluate", str(copy / "calibration.yaml"), str(recording), "-q"])
    assert result.exit_code == 0, result.output
    again, first = (yaml.safe_load((f / "evaluation.yaml").read_text()) for f in (copy, folder))
    for which in ("before", "after", "after_gauge_free"):
        assert again["cloud_to_cloud_m"][which] == pytest.approx(first["cloud_to_cloud_m"][which], rel=1e-9)
    assert again["energy_cm2"] == pytest.approx(first["energy_cm2"]) and "c2c mean cm" in result.output
    renamed = tmp_path / "renamed"  # a calibration file of another name: its own energies, nothing else read
    renamed.mkdir()
    shutil.copy(folder / "calibration.yaml", renamed / "mine.yaml")
    result = CliRunner().invoke(app, ["evaluate", str(renamed / "mine.yaml"), str(recording), "-q"])
    assert result.exit_code == 0, result.output
    assert yaml.safe_load((renamed / "evaluation.yaml").read_text())["energy_cm2"] == pytest.approx(first["energy_cm2"])
    real = shutil.copytree(recording, tmp_path / "real", ignore=shutil.ignore_patterns("truth"))
    result = CliRunner().invoke(app, ["evaluate", str(folder), str(real)])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    assert f"{real / 'truth'}: not found" in result.output


@pytest.mark.parametrize("suffix", [".laz", ".ply"])
def test_apply_writes_the_corrected_cloud_georeferenced(calibrated, tmp_path, monkeypatch, suffix):
    recording_path, folder = calibrated
    monkeypatch.setattr("graphcal.calibration.corrected_cloud.BATCH_ROWS", 30_000)  # in several batches
    out = tmp_path / f"cloud{suffix}"
    result = CliRunner().invoke(app, ["apply", str(folder), str(recording_path), "--out", str(out), "-q"])
    assert result.exit_code == 0, result.output
    recording = Recording.load(recording_path)
    expected = graphcal.apply_calibration(graphcal.Calibration.load(folder, recording.sensor), recording)
    columns = recording.points.read(["time", "fibre"])
    residuals = pq.read_table(folder / "residuals.parquet")
    if suffix == ".laz":
        las = laspy.read(out)
        assert las.header.parse_crs() == recording.world.crs
        assert las.header.generating_software == f"graphcal {graphcal.__version__}"
        np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), expected, atol=5.1e-5)
        np.testing.assert_array_equal(las.gps_time, columns["time"])
        np.testing.assert_array_equal(las.fibre, columns["fibre"])
        residual = np.asarray(las.residual_m)
    else:
        import open3d as o3d

        header = out.read_bytes()[:400].decode("ascii", "replace")
        assert f"comment crs {recording.world.crs.to_string()}" in header
        cloud = o3d.t.io.read_point_cloud(str(out))
        np.testing.assert_allclose(cloud.point.positions.numpy(), expected, atol=1e-6)  # batches: other origins
        residual = cloud.point["residual_m"].numpy().ravel()
    rows, values = residuals.column("row").to_numpy(), residuals.column("residual_m").to_numpy()
    assert np.isfinite(residual).sum() == len(np.unique(rows))
    for row in rows[:50]:  # RMS over the pairs the return is p of
        assert residual[row] == pytest.approx(np.sqrt(np.mean(values[rows == row].astype(float) ** 2)), rel=1e-6)


def test_apply_of_a_nominal_calibration_with_a_batch_of_one_return(calibrated, tmp_path, monkeypatch):
    """The nominal calibration has no control times: each batch gets two of its own, which used to
    be equal (NaN points written as the most negative LAS integer) for a batch of one return."""
    recording = Recording.load(calibrated[0])
    nominal = nominal_calibration(recording)
    monkeypatch.setattr("graphcal.calibration.corrected_cloud.BATCH_ROWS", len(recording.points) - 1)
    las = laspy.read(write_corrected_cloud(tmp_path / "nominal.las", nominal, recording, quiet=True))
    np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), graphcal.apply_calibration(nominal, recording),
                               atol=5.1e-5)


def test_version_quiet_and_help_in_80_columns_on_every_command(calibrated):
    import typer

    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"graphcal {graphcal.__version__}"

    def leaves(group, prefix: list[str]):
        for name, command in group.commands.items():
            yield from leaves(command, prefix + [name]) if hasattr(command, "commands") else [prefix + [name]]

    commands = list(leaves(typer.main.get_command(app), []))
    assert len(commands) >= 14
    for command in [[]] + commands:
        shown = CliRunner().invoke(app, command + ["--help"], env={"COLUMNS": "80"}).output
        assert "--quiet" in shown or not command, command
        if command:  # -q says what it does
            quiet_line = next(line for line in shown.splitlines() if "--quiet" in line)
            assert quiet_line.split("<bool>")[-1].strip(" \u2502"), (command, quiet_line)
        assert max(len(line) for line in shown.splitlines()) <= 80, command
        assert "\u2026" not in shown, (command, shown)  # nothing cut off to fit
    result = CliRunner().invoke(app, ["info", str(calibrated[0]), "-q"])
    assert result.exit_code == 0 and result.output == ""


def test_apply_says_which_effects_of_a_diagnosis_it_does_not_apply(calibrated, tmp_path, monkeypatch):
    """A calibration.yaml with a diagnosis's effects: the cloud is the calibration's without them, and both the
    command's output and run.yaml name them."""
    recording_path, folder = calibrated
    copy = tmp_path / "diagnosed"
    shutil.copytree(folder, copy)
    calibration = yaml.safe_load((copy / "calibration.yaml").read_text())
    calibration["effects"] = [{"effect": "time_offset", "magnitude": 0.004, "sigma": 0.0005, "unit": "s",
                               "parameters": [0.004], "statement": "a latency"}]
    (copy / "calibration.yaml").write_text(yaml.safe_dump(calibration))
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["apply", str(copy), str(recording_path)])
    assert result.exit_code == 0, result.output
    assert "time_offset" in result.output and "not applied" in result.output
    (run,) = (tmp_path / "runs").glob("*apply*")
    assert yaml.safe_load((run / "run.yaml").read_text())["effects_not_applied"] == ["time_offset"]


def test_apply_refuses_a_file_name_it_cannot_write(calibrated, tmp_path):
    recording = Recording.load(calibrated[0])
    with pytest.raises(ConfigError, match=r"cloud.xyz: expected a .las, .laz, .ply file name"):
        write_corrected_cloud(tmp_path / "cloud.xyz", nominal_calibration(recording), recording, quiet=True)
    result = CliRunner().invoke(app, ["apply", str(calibrated[1]), str(calibrated[0]), "--out", str(tmp_path / "c.xyz")])
    assert result.exit_code == 2 and "expected a .las, .laz, .ply file name" in result.output
    assert not list(tmp_path.iterdir())
    (tmp_path / "folder.laz").mkdir()
    result = CliRunner().invoke(app, ["apply", str(calibrated[1]), str(calibrated[0]), "--out",
                                      str(tmp_path / "folder.laz")])
    assert result.exit_code == 2 and "folder.laz: a directory" in result.output
    assert not list((tmp_path / "folder.laz").iterdir())


def test_las_refuses_a_point_that_is_not_finite_and_names_it(tmp_path):
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    with (pytest.raises(ConfigError, match=r"cloud.las: point 3 has a coordinate that is not finite"),
          las_writer(tmp_path / "cloud.las", np.zeros(3)) as write):
        write(xyz)
        write(np.array([[7.0, 8.0, 9.0], [np.nan, 0.0, 0.0]]))
    assert not (tmp_path / "cloud.las").exists()  # nothing half written


def test_view_without_a_display_says_what_to_do(calibrated, monkeypatch):
    _, folder = calibrated
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = CliRunner().invoke(app, ["view", str(folder)])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    assert "no display" in result.output and "--web" in result.output
    result = CliRunner().invoke(app, ["view", str(folder / "missing.rrd")])
    assert result.exit_code == 2 and "file not found" in result.output


def test_deskew_run_rrd_shows_raw_and_deskewed_revolutions(tmp_path):
    recording = graphcal.simulate(load_scenario_builder("deskew_rotation")(size=0.005), quiet=True)
    path = recording.save(tmp_path / "rec")
    result = CliRunner().invoke(app, ["deskew", str(path), "--out", str(tmp_path / "run"), "--viewer-points", "2000",
                                      "-q"])
    assert result.exit_code == 0, result.output
    scans = yaml.safe_load((tmp_path / "run" / "deskew.yaml").read_text())["scans"]
    chunks = _chunks(tmp_path / "run" / "run.rrd")
    for name in ("raw", "deskewed"):
        assert sorted(set(_column(chunks[f"/deskew/{name}"], "scan"))) == list(range(scans))
        (world,) = _column(chunks[f"/world/deskew/{name}"], "Points3D:positions")
        assert 1000 <= len(world) <= 2 * 2000
    assert "timings_s" in yaml.safe_load((tmp_path / "run" / "run.yaml").read_text())


def test_spawn_without_a_display_warns_and_writes_the_file_whole(tmp_path, monkeypatch, capsys):
    from graphcal.viewer.log import log_summary
    from graphcal.viewer.stream import recording_stream

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with recording_stream(tmp_path / "run.rrd", "test", spawn=True) as stream:
        log_summary(stream, "# a run")
    assert "no live viewer, no display" in capsys.readouterr().err
    assert "/summary" in RrdReader(tmp_path / "run.rrd").store().schema().entity_paths()
    with pytest.raises(RuntimeError), recording_stream(tmp_path / "failed.rrd", "test") as stream:
        log_summary(stream, "# half a run")
        raise RuntimeError("the run fails half way")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]  # no file, no temporary left


def test_run_folder_names_times_and_links_the_latest(tmp_path):
    from graphcal.common.errors import RecordingError
    from graphcal.common.run_folder import RunFolder, read_manifest

    first = RunFolder.create(None, "sim6_turn", "calibrate", root=tmp_path)
    assert re.fullmatch(r"sim6_turn-calibrate-\d{8}T\d{6}Z", first.final.name)
    with first.stage("solve"):
        pass
    with first.stage("solve"):  # a stage run twice adds up
        pass
    first.finish(recording="/data/rec")
    assert not first.final.exists()  # written aside until complete
    assert first.publish() == first.final and first.path == first.final
    manifest = read_manifest(first.path)
    assert manifest["recording"] == "/data/rec" and list(manifest["timings_s"]) == ["solve"]
    second = RunFolder.create(tmp_path / "second", "sim6_turn", "deskew-ins", root=tmp_path)
    second.publish()
    assert (tmp_path / "latest").resolve() == first.path.resolve()  # an explicit --out is not "latest"
    assert second.path == tmp_path / "second"
    with pytest.raises(RecordingError, match="not a graphcal run manifest|file not found"):
        read_manifest(second.path)


def test_a_re_run_into_an_existing_folder_replaces_it_whole_or_not_at_all(tmp_path):
    """A run interrupted half way (here an error; a SIGKILL leaves only a hidden .partial folder) leaves the previous
    run at --out as it was; a complete one replaces it whole, with none of the old files beside the new."""
    from graphcal.common.run_folder import RunFolder, abandon_unpublished

    old = RunFolder.create(tmp_path / "run", "rec", "calibrate")
    for name in ("calibration.yaml", "report.html", "run.rrd"):
        (old.path / name).write_text("old")
    old.finish(recording="/data/rec")
    old.publish()
    half = RunFolder.create(tmp_path / "run", "rec", "calibrate")
    (half.path / "calibration.yaml").write_text("new")
    abandon_unpublished()  # what the command line does on an error (and the interpreter at exit)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert {p.name: p.read_text() for p in (tmp_path / "run").iterdir() if p.suffix != ".yaml" or
            p.name == "calibration.yaml"} == {"calibration.yaml": "old", "report.html": "old", "run.rrd": "old"}
    whole = RunFolder.create(tmp_path / "run", "rec", "calibrate")
    (whole.path / "calibration.yaml").write_text("new")
    whole.finish(recording="/data/rec")
    whole.publish()
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["calibration.yaml", "run.yaml"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_re_run_into_an_existing_out_is_refused_unless_forced(calibrated, tmp_path):
    """graphcal replaces nothing silently: a run folder or a cloud already at --out is refused (exit 2, one line
    naming it and --force) before any work, and left as it was; with --force it is replaced."""
    recording_path, folder = calibrated
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    for command in (["calibrate", str(recording_path)], ["diagnose", str(recording_path)],
                    ["deskew", str(recording_path)], ["simulate", "sim2_street"]):
        result = CliRunner().invoke(app, command + ["--out", str(folder)])
        assert result.exit_code == 2 and result.output.count("\n") == 1, (command, result.output)
        assert str(folder) in result.output and "--force" in result.output
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == before
    cloud = tmp_path / "cloud.ply"
    apply = ["apply", str(folder), str(recording_path), "--out", str(cloud), "-q"]
    assert CliRunner().invoke(app, apply).exit_code == 0
    cloud.write_bytes(b"old")
    result = CliRunner().invoke(app, apply)
    assert result.exit_code == 2 and "--force" in result.output and cloud.read_bytes() == b"old"
    assert CliRunner().invoke(app, apply + ["--force"]).exit_code == 0 and cloud.read_bytes() != b"old"


def test_trajectory_corrections_apply_only_to_their_own_drive(calibrated, tmp_path):
    """calibration.yaml records the drive it was made on: its trajectory corrections are refused on another drive
    (the same scenario with another seed spans the same times with the same number of returns), for apply and
    evaluate, and written again from the file it is the same drive."""
    recording_path, folder = calibrated
    assert yaml.safe_load((folder / "calibration.yaml").read_text())["drive"]["name"] == Recording.load(
        recording_path).name
    other = graphcal.simulate(SIM6(size=0.02, seed=2), quiet=True).save(tmp_path / "other")
    for command in (["apply", str(folder), str(other), "--out", str(tmp_path / "cloud.laz")],
                    ["evaluate", str(folder), str(other)]):
        result = CliRunner().invoke(app, command)
        assert result.exit_code == 2 and "trajectory corrections were made on" in result.output, result.output
        assert "calibration.yaml: " in result.output  # the file at fault, not the cloud to write
    assert not (tmp_path / "cloud.laz").exists()
    calibration = graphcal.Calibration.load(folder, Recording.load(recording_path).sensor)
    from graphcal.calibration.result import drive_of
    assert calibration.drive == drive_of(Recording.load(recording_path))


def test_evaluating_against_another_drive_leaves_the_runs_own_evaluation(calibrated, tmp_path):
    """A calibration without trajectory corrections applies to any drive of the unit: evaluated against another
    drive's truth, the result goes to evaluation-<recording>.yaml beside it, naming that recording, and the run's
    own evaluation.yaml and report are not rewritten with another drive's figures."""
    recording_path, folder = calibrated
    copy = shutil.copytree(folder, tmp_path / "copy")
    data = yaml.safe_load((copy / "calibration.yaml").read_text())
    data.pop("trajectory_corrections", None)
    (copy / "calibration.yaml").write_text(yaml.safe_dump(data))
    own, report = ((copy / name).read_bytes() for name in ("evaluation.yaml", "report.html"))
    other = graphcal.simulate(SIM6(size=0.02, seed=2), quiet=True).save(tmp_path / "other")
    result = CliRunner().invoke(app, ["evaluate", str(copy), str(other)])
    assert result.exit_code == 0, result.output
    written = copy / f"evaluation-{Recording.load(other).name}.yaml"
    assert f"wrote {written}" in result.output
    again = yaml.safe_load(written.read_text())
    assert again["recording"] == str(other)
    assert all(math.isnan(v) for v in again["energy_cm2"])  # the calibration's J is its own drive's, not this one's
    assert (copy / "evaluation.yaml").read_bytes() == own and (copy / "report.html").read_bytes() == report


def test_what_a_killed_process_left_is_removed_by_the_next_write_of_the_same_name(tmp_path):
    """A process killed (SIGKILL) inside an atomic write or a run leaves its hidden working folder; the next write
    of the same name on this host removes it, and leaves alone what a live process or another host is writing."""
    import os
    import signal
    import socket
    import subprocess
    import sys

    from graphcal.common.atomic import atomic_directory, atomic_path
    from graphcal.common.run_folder import RunFolder

    killed = """
import os, signal, sys
from pathlib import Path
from graphcal.common.atomic import atomic_directory, atomic_path
from graphcal.common.run_folder import RunFolder
root = Path(sys.argv[1])
run = RunFolder.create(root / "run", "rec", "calibrate")
(run.path / "calibration.yaml").write_text("half")
with atomic_path(root / "cloud.laz") as tmp:
    tmp.write_text("half")
    with atomic_directory(root / "rec") as folder:
        (folder / "points.parquet").write_text("half")
        os.kill(os.getpid(), signal.SIGKILL)
"""
    child = subprocess.run([sys.executable, "-c", killed, str(tmp_path)])
    assert child.returncode == -signal.SIGKILL
    left = sorted(p.name for p in tmp_path.iterdir())
    assert len(left) == 3 and all(name.startswith((".run.partial-", ".cloud.laz.", ".rec.")) for name in left), left
    elsewhere = tmp_path / f".rec.other-{socket.gethostname()}-999999.abc.tmp"  # another host's
    live = tmp_path / f".rec.{socket.gethostname()}-{os.getpid()}.abc.tmp"  # a process still writing
    elsewhere.mkdir()
    live.mkdir()
    with atomic_directory(tmp_path / "rec") as folder:
        (folder / "points.parquet").write_text("whole")
    with atomic_path(tmp_path / "cloud.laz") as tmp:
        tmp.write_text("whole")
    run = RunFolder.create(tmp_path / "run", "rec", "calibrate")
    run.finish(recording="/data/rec")
    run.publish()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([elsewhere.name, live.name, "cloud.laz", "rec", "run"])


def test_an_interrupted_calibrate_says_so_and_resume_goes_on_from_its_checkpoint(calibrated, tmp_path, monkeypatch):
    """Ctrl-C after the second outer iteration: exit 130, no run folder, the checkpoint beside it; --resume ends
    the calibration from there (the outer iterations of the module's uninterrupted run) and removes it."""
    from graphcal.calibration.checkpoint import Checkpoint

    recording, folder = calibrated
    settings, out = folder.parent / "settings.yaml", tmp_path / "run"
    checkpoint = tmp_path / ".run.checkpoint.npz"
    save, saves = Checkpoint.save, []

    def interrupted(self, state):
        save(self, state)
        saves.append(state.inside)
        if len(saves) == 3:
            raise KeyboardInterrupt

    command = ["calibrate", str(recording), "--mode", "trajectory", "--config", str(settings), "--out", str(out),
               "--viewer-points", str(VIEWER_POINTS)]
    monkeypatch.setattr(Checkpoint, "save", interrupted)
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 130 and "Traceback" not in result.output, result.output
    assert f"kept in {checkpoint}: the same command with --resume" in result.output
    assert checkpoint.is_file() and not out.exists()
    monkeypatch.setattr(Checkpoint, "save", lambda self, state: saves.append(state.inside) or save(self, state))
    result = CliRunner().invoke(app, command + ["--resume", "-q"])
    assert result.exit_code == 0, result.output
    assert saves[3] == (0, 3), saves[3:]  # went on with the third outer iteration
    assert not checkpoint.exists() and (out / "calibration.yaml").is_file()
    assert [row["energy_cm2"] for row in _history(out)] == [row["energy_cm2"] for row in _history(folder)]


def test_a_calibrate_killed_mid_run_resumes_from_its_checkpoint(calibrated, tmp_path):
    """SIGKILL right after the third save (inside the coarse phase): the checkpoint is whole, the run's working
    folder is left hidden; --resume removes that folder, ends the calibration with the uninterrupted run's outer
    iterations, and removes the checkpoint."""
    import signal
    import subprocess
    import sys

    recording, folder = calibrated
    command = ["calibrate", str(recording), "--mode", "trajectory", "--config", str(folder.parent / "settings.yaml"),
               "--out", str(tmp_path / "run"), "--viewer-points", str(VIEWER_POINTS), "-q"]
    killed = f"""
import os, signal
from graphcal.calibration.checkpoint import Checkpoint
from graphcal.cli.main import app
save, saves = Checkpoint.save, []
def then_killed(self, state):
    save(self, state)
    saves.append(state)
    if len(saves) == 3:
        os.kill(os.getpid(), signal.SIGKILL)
Checkpoint.save = then_killed
app({command!r})
"""
    child = subprocess.run([sys.executable, "-c", killed])
    assert child.returncode == -signal.SIGKILL
    assert (tmp_path / ".run.checkpoint.npz").is_file() and not (tmp_path / "run").exists()
    result = CliRunner().invoke(app, command + ["--resume"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # the checkpoint and the killed run's folder gone
    assert [row["energy_cm2"] for row in _history(tmp_path / "run")] == [row["energy_cm2"]
                                                                         for row in _history(folder)]


def test_a_second_calibrate_of_the_same_checkpoint_is_refused_and_leaves_it(calibrated, tmp_path):
    """Two runs with the same checkpoint (the same recording without --out, or the same --out): while one holds
    it, the other is refused naming the file and the process holding it, before any calibration, and neither
    removes the checkpoint nor leaves a folder; once it is released the lock file is gone."""
    import os

    from graphcal.common.lock import held_alone

    recording, folder = calibrated
    out, checkpoint = tmp_path / "run", tmp_path / ".run.checkpoint.npz"
    checkpoint.write_bytes(b"the first run's state")
    command = ["calibrate", str(recording), "--mode", "trajectory", "--config", str(folder.parent / "settings.yaml"),
               "--out", str(out), "-q"]
    with held_alone(checkpoint, "graphcal calibrate"):
        result = CliRunner().invoke(app, command)
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    assert f"{checkpoint}: held by another graphcal calibrate (process {os.getpid()})" in " ".join(result.output.split())
    assert checkpoint.read_bytes() == b"the first run's state" and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [checkpoint.name]
