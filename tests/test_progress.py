"""Progress bars (graphcal.common.progress) are drawn on a terminal only: piped or logged output gets no bar and
no blank line where one was."""

from graphcal.common.progress import progress, status


def test_without_a_terminal_nothing_is_printed(capsys, monkeypatch):
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
