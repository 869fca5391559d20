"""Subsets of a long drive's returns (graphcal.recording.subset): spans spread along the drive at a stated
density, against the times of the rows drawn."""

import numpy as np
import pytest

from graphcal.recording.points import PointTable
from graphcal.recording.subset import MIN_SPAN_S, rows_before, spread_spans_s, subset_rows
from conftest import city_drive


def _drive(duration_s=300.0, per_s=1000):
    """A drive's returns: per_s a second at random times over duration_s, in time order."""
    rng = np.random.default_rng(3)
    time_s = np.sort(rng.uniform(100.0, 100.0 + duration_s, int(duration_s * per_s)))
    n = len(time_s)
    return PointTable.from_arrays(time=time_s, fibre=np.zeros(n), range=np.ones(n), azimuth=np.zeros(n),
                                  intensity=np.zeros(n))


def test_spans_hold_the_total_spread_evenly():
    spans = spread_spans_s(0.0, 300.0, 50.0)
    assert len(spans) == 3  # 50 s in spans of at least 16 s
    assert np.diff(spans, axis=1).sum() == pytest.approx(50.0)
    assert np.all(np.diff(spans, axis=1) >= MIN_SPAN_S)
    assert np.diff(spans.mean(axis=1)) == pytest.approx([100.0, 100.0])  # centres a third of the drive apart
    assert spans[0, 0] >= 0.0 and spans[-1, 1] <= 300.0
    assert spread_spans_s(0.0, 300.0, 10.0).tolist() == [[145.0, 155.0]]  # shorter than a span: one, in the middle
    assert spread_spans_s(0.0, 30.0, 40.0).tolist() == [[0.0, 30.0]]


def test_the_time_span_is_read_from_the_first_and_last_row_groups(monkeypatch, tmp_path):
    monkeypatch.setattr("graphcal.recording.points.BATCH_ROWS", 777)
    points = _drive(60.0, 100)
    points.save(tmp_path / "points.parquet")
    saved = PointTable.open(tmp_path / "points.parquet")
    time_s = points.read(["time"])["time"]
    assert saved.time_span_s() == points.time_span_s() == (time_s[0], time_s[-1])


def test_rows_before_counts_across_batches(monkeypatch):
    monkeypatch.setattr("graphcal.recording.points.BATCH_ROWS", 777)
    points = _drive(60.0, 100)
    times = np.array([99.0, 110.0, 130.5, 170.0])
    expected = np.searchsorted(points.read(["time"])["time"], times)
    assert rows_before(points, times).tolist() == expected.tolist()


def test_a_long_drive_is_drawn_in_spans_at_the_stated_density():
    points = _drive()
    time_s = points.read(["time"])["time"]
    rows, spans = subset_rows(points, 40_000, np.random.default_rng(0), points_per_s=800.0)
    assert len(rows) == 40_000 and np.all(np.diff(rows) > 0)
    assert np.diff(spans, axis=1).sum() == pytest.approx(50.0)  # 40 000 returns at 800 a second
    inside = np.zeros(len(rows), bool)
    for start, stop in spans:
        inside |= (time_s[rows] >= start) & (time_s[rows] < stop)
    assert inside.all()
    # every span is drawn at the same density: 800 of its 1000 returns a second
    for start, stop in spans:
        held = ((time_s >= start) & (time_s < stop)).sum()
        drawn = ((time_s[rows] >= start) & (time_s[rows] < stop)).sum()
        assert drawn / held == pytest.approx(0.8, abs=0.02)


def test_a_drive_no_denser_than_asked_is_drawn_whole_as_without_a_density():
    points = _drive()
    rows, spans = subset_rows(points, 40_000, np.random.default_rng(0), points_per_s=100.0)
    plain, none = subset_rows(points, 40_000, np.random.default_rng(0))
    assert spans is None and none is None and rows.tolist() == plain.tolist()
    assert subset_rows(points, None, np.random.default_rng(0))[0].tolist() == list(range(len(points)))


@pytest.fixture(scope="module")
def city_minute(tmp_path_factory):
    return city_drive(tmp_path_factory.mktemp("city") / "drive", 40.0, 0.005, 2)


def test_a_calibration_without_trajectory_reads_spans_and_one_with_it_refuses(city_minute):
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.calibration.problem import Problem
    from graphcal.common.errors import ConfigError

    config = CalibrationConfig(mode="joint", max_points=5000, points_per_s=200.0)
    data = Problem.of(city_minute, config).full
    assert len(data.time_s) == 5000 and np.diff(data.spans_s, axis=1).sum() == pytest.approx(25.0)
    assert np.all((data.time_s >= data.spans_s[0, 0]) & (data.time_s < data.spans_s[-1, 1]))
    with pytest.raises(ConfigError, match="whole drive.*points_per_s 200"):
        Problem.of(city_minute, config.model_copy(update={"mode": "joint_trajectory"}))
