"""Scenario scripts run alone and write valid recordings; the command line fails cleanly."""

import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.main import app
from graphcal.cli.demo import run_demo
from graphcal.recording.directory import Recording
from graphcal.simulation.script import SCENARIOS_DIR, load_scenario_builder

SCENARIOS = ["sim2_street", "sim6_turn", "deskew_linear", "deskew_rotation"]


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_script_runs_alone(name, tmp_path):
    out = tmp_path / name
    subprocess.run([sys.executable, str(SCENARIOS_DIR / f"{name}.py"), "--out", str(out), "--size", "0.02",
                    "--seed", "1", "--quiet"], check=True)
    recording = Recording.load(out)
    assert len(recording.points) > 10_000 and recording.truth is not None


def test_scenarios_match_their_specification():
    sim2 = load_scenario_builder("sim2_street")(size=0.5, seed=0)
    assert sim2.sensor_model == "HDL-32E" and sim2.intrinsic_errors.rms == (0.10, 2.5, 3.0, 0.10)
    assert sim2.intrinsic_errors.bounds == (0.10, 3.0, 3.0, 0.10) and sim2.size == 0.5
    sim6 = load_scenario_builder("sim6_turn")()
    assert sim6.ins.piecewise_error_m == 0.35 and 5.0 <= sim6.duration_s <= 6.0 and sim6.effects == {}
    turned = load_scenario_builder("sim6_turn")(heading_error_deg=0.5, piecewise_error_m=0.0)
    assert turned.effects == {"heading_bias": {"bias_deg": 0.5}} and turned.ins.piecewise_error_m == 0.0
    joint_start = load_scenario_builder("sim2_street")(start="section_4_5_2")
    assert joint_start.extrinsic.error_lever_arm_m == (0.5, 0.5, 0.8)
    assert joint_start.extrinsic.error_boresight_deg == (2.5, 3.0, -2.0)
    assert joint_start.intrinsic_errors.rms == (0.03, 0.3, 0.3, 0.03)
    assert sum(obj.kind == "facade" for obj in sim6.scene) == 4
    for name, speed in (("deskew_linear", 10.0), ("deskew_rotation", 5.0)):
        scenario = load_scenario_builder(name)()
        assert scenario.sensor_model == "HDL-64E" and scenario.rotation_hz == 10.0
        assert scenario.drive.speed_knots == [(0.0, speed)]
    arc = load_scenario_builder("deskew_rotation")().drive.segments[0]
    assert np.degrees(5.0 / arc.radius_m) == pytest.approx(25.0)  # 25 deg/s yaw rate


def test_cli_simulate_and_info(tmp_path):
    runner = CliRunner()
    out = tmp_path / "rec"
    result = runner.invoke(app, ["simulate", "sim6_turn", "--size", "0.02", "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["info", str(out)])
    assert result.exit_code == 0 and "HDL-32E" in result.output and "EPSG:32631" in result.output


def test_cli_bad_input_is_one_clear_line(tmp_path):
    result = CliRunner().invoke(app, ["info", str(tmp_path / "missing")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [f"error: {tmp_path / 'missing'}: recording directory not found"]
    result = CliRunner().invoke(app, ["simulate", "no_such_scenario"])
    assert result.exit_code == 2 and "sim6_turn" in result.output and "Traceback" not in result.output


def test_demo_runs_end_to_end_and_sharpens_the_cloud(tmp_path):
    figures = run_demo(tmp_path / "demo", size=0.01, max_points=5000, max_outer_iterations=2, quiet=True)
    # a 0.35 m piecewise-linear INS error: centimetres of blur, not millimetres or metres
    assert 0.02 < figures["cloud_before"].mean < 0.3
    assert figures["cloud_after_gauge_free"].mean < figures["cloud_before"].mean
    assert figures["energy_cm2"][1] < figures["energy_cm2"][0]
    for name in ("recording/recording.yaml", "calibration.yaml", "run.rrd", "report.html", "run.yaml"):
        assert (tmp_path / "demo" / name).is_file(), name


def _quick_calibration(runner: CliRunner, tmp_path) -> tuple:
    """A small sim2_street recording and settings for a quick look at it: (recording folder, settings file)."""
    recording = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "sim2_street", "--out", str(recording), "--size", "0.01", "-q"]).exit_code == 0
    settings = tmp_path / "settings.yaml"
    # Table 4.1's start is no factory calibration: its stated uncertainty is wide; a quick look may stop early
    settings.write_text("stopping: {max_outer_iterations: 2, refuse_unconverged: false}\n"
                        "priors: {intrinsic_range_m: 0.3, intrinsic_angle_deg: 10}\n")
    return recording, settings


def test_cli_calibrate_writes_a_run_folder_and_rejects_a_bad_config(tmp_path):
    runner = CliRunner()
    recording, settings = _quick_calibration(runner, tmp_path)
    result = runner.invoke(app, ["calibrate", str(recording), "--config", str(settings), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "J " in result.output and (tmp_path / "run" / "calibration.yaml").is_file()
    settings.write_text("stopping: {max_outer_iterations: 0}\n")
    result = runner.invoke(app, ["calibrate", str(recording), "--config", str(settings)])
    assert result.exit_code == 2 and "max_outer_iterations" in result.output and "Traceback" not in result.output
    settings.write_text("max_outer_iterations: 5\nhold: ['fibre_3.h_z_m']\n")  # the former flat layout
    result = runner.invoke(app, ["calibrate", str(recording), "--config", str(settings)])
    assert result.exit_code == 2 and "max_outer_iterations -> stopping.max_outer_iterations" in result.output
    assert "hold -> static.hold" in result.output and "Traceback" not in result.output
    settings.write_text("- mode: joint\n")
    result = runner.invoke(app, ["calibrate", str(recording), "--config", str(settings)])
    assert result.exit_code == 2 and "settings.yaml: not a mapping" in result.output
    for address in ("local:0", "somewhere"):  # refused before any run folder is made
        result = runner.invoke(app, ["calibrate", str(recording), "--dask", address, "--out", str(tmp_path / "d")])
        assert result.exit_code == 2 and f"--dask {address!r}: expected local" in result.output, result.output
        assert not (tmp_path / "d").exists()


def test_cli_calibrate_hands_dask_to_the_calibration(tmp_path, monkeypatch):
    """--dask reaches calibrate's task map (here recorded, the tiles then run in this process)."""
    from contextlib import contextmanager

    from graphcal.common.cluster import IN_PROCESS

    asked = []

    @contextmanager
    def recorded(address, quiet=True):
        asked.append(address)
        yield IN_PROCESS

    monkeypatch.setattr("graphcal.calibration.calibrate.open_task_map", recorded)
    runner = CliRunner()
    recording, settings = _quick_calibration(runner, tmp_path)
    result = runner.invoke(app, ["calibrate", str(recording), "--config", str(settings), "--dask", "tcp://10.0.0.5:8786",
                                 "--out", str(tmp_path / "run"), "-q"])
    assert result.exit_code == 0, result.output
    assert asked == ["tcp://10.0.0.5:8786"]


@pytest.mark.parametrize("size", ["0", "nan", "-1"])
def test_simulate_refuses_a_size_out_of_range_in_one_line(size, tmp_path):
    result = CliRunner().invoke(app, ["simulate", "sim6_turn", "--size", size, "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 2 and "size" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "rec").exists()


def test_run_folders_stay_inside_runs_and_out_must_be_a_folder(tmp_path):
    from graphcal.common.errors import ConfigError
    from graphcal.common.run_folder import RunFolder

    run = RunFolder.create(None, "../../../x", "calibrate", root=tmp_path / "runs")
    assert run.path.parent == tmp_path / "runs" and run.path.resolve().is_relative_to((tmp_path / "runs").resolve())
    (tmp_path / "a_file").write_text("not a folder")
    with pytest.raises(ConfigError, match="a_file: --out names a file"):
        RunFolder.create(tmp_path / "a_file", "rec", "calibrate")


def test_calibrate_refuses_a_recording_too_small_to_pair(tmp_path):
    """A recording that `info` accepts but that holds too few returns to pair: one line, exit 2, no run folder."""
    runner = CliRunner()
    out = tmp_path / "tiny"
    assert runner.invoke(app, ["simulate", "sim6_turn", "--size", "0.001", "--out", str(out), "-q"]).exit_code == 0
    assert runner.invoke(app, ["info", str(out)]).exit_code == 0
    result = runner.invoke(app, ["calibrate", str(out), "--out", str(tmp_path / "run"), "-q"])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert "returns; a calibration needs at least 10,000" in result.output and not (tmp_path / "run").exists()


@pytest.mark.parametrize("script, words", [("def scenario(:\n", "line 1: invalid syntax"),
                                           ("import math\nx = 1 / 0\n", "line 2: ZeroDivisionError"),
                                           ("def scenario(size, seed):\n    raise RuntimeError('boom')\n",
                                            "line 2: RuntimeError: boom (the scenario script's scenario() failed)"),
                                           ("def scenario(size, seed):\n    return 42\n",
                                            "gave a value of type int, expected a graphcal Scenario")])
def test_a_broken_scenario_script_is_one_line(script, words, tmp_path):
    path = tmp_path / "broken.py"
    path.write_text(script)
    result = CliRunner().invoke(app, ["simulate", str(path), "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and words in result.output, result.output
