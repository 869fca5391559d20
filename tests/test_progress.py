"""Progress bars (graphcal.common.progress) are drawn on a terminal only: piped or logged output gets no bar and
no blank line where one was, only a plain line now and then from a loop that runs long."""

from graphcal.common.progress import progress, status


def test_without_a_terminal_a_short_loop_prints_nothing(capsys, monkeypatch):
    for name in ("TTY_COMPATIBLE", "FORCE_COLOR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.delenv("GRAPHCAL_QUIET", raising=False)
    assert list(progress(range(5), "counting")) == [0, 1, 2, 3, 4]
    with status("waiting"):
        pass
    assert capsys.readouterr() == ("", "")


def test_on_a_terminal_the_bar_goes_to_stderr_and_quiet_silences_it(capsys, monkeypatch):
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # rich's switch: stderr taken as a terminal
    monkeypatch.delenv("GRAPHCAL_QUIET", raising=False)
    assert list(progress(range(5), "counting")) == [0, 1, 2, 3, 4]
    out, err = capsys.readouterr()
    assert out == "" and "counting" in err
    assert list(progress(range(5), "counting", quiet=True)) == [0, 1, 2, 3, 4]
    assert capsys.readouterr() == ("", "")


def test_without_a_terminal_a_long_loop_writes_plain_lines_with_the_time_left(capsys, monkeypatch):
    """A line after each LOG_EVERY_S (here every item): how far, the seconds spent and, with a total, left."""
    for name in ("TTY_COMPATIBLE", "FORCE_COLOR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.delenv("GRAPHCAL_QUIET", raising=False)
    monkeypatch.setattr("graphcal.common.progress.LOG_EVERY_S", 0.0)
    assert list(progress(range(4), "counting", total=4)) == [0, 1, 2, 3]
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert out == "" and len(lines) == 4 and lines[0].startswith("counting: 1/4 after 0 s, about 0 s left")
    assert list(progress(range(2), "counting", quiet=True)) == [0, 1] and capsys.readouterr() == ("", "")


def test_a_calibration_names_each_step_on_a_terminal(capsys, monkeypatch):
    """Besides the outer iterations' bar, a spinner names the steps that draw none (the weak directions, the final
    fit), so that a long step is not a silent one."""
    import graphcal
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.01, seed=0), quiet=True)
    monkeypatch.setenv("TTY_COMPATIBLE", "1")
    monkeypatch.delenv("GRAPHCAL_QUIET", raising=False)
    config = graphcal.CalibrationConfig(mode="intrinsic", stopping={"max_outer_iterations": 1,
                                                                    "refuse_unconverged": False},
                                        priors={"intrinsic_range_m": 0.3, "intrinsic_angle_deg": 10})
    graphcal.calibrate(recording, config)
    err = capsys.readouterr().err
    for step in ("calibrating: prepare", "calibrating: weak directions at the start", "calibrating (intrinsic",
                 "calibrating: final fit and marginals"):
        assert step in err, step
