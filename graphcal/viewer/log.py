"""log_* functions: one kind of thing each, into a given RecordingStream, arrays in and nothing out.

Positions are stored as float32 by rerun: callers pass them relative to a local origin [m]
(a few hundred metres at most keeps 0.03 mm resolution) and say which origin in the summary.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from graphcal.viewer.colors import value_colors

VIEWER_POINTS = 1_000_000  # default most returns drawn per cloud (a random subset, seeded, or every k-th)
POINT_RADIUS_UI = -1.5  # negative: a size in screen points, whatever the zoom
LINE_RADIUS_UI = -2.0


def log_summary(stream: rr.RecordingStream, markdown: str, path: str = "summary") -> None:
    """A Markdown document (what ran, the figures, where things are)."""
    stream.log(path, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)


def log_cloud(stream: rr.RecordingStream, path: str, xyz_local_m: np.ndarray, *, fibre: np.ndarray | None = None,
              time_s: tuple[np.ndarray, float, float] | None = None,
              residual_m: tuple[np.ndarray, float] | None = None) -> None:
    """One cloud under `path`, once per colouring given: path/by_fibre (class id = fibre: colour
    and label from the annotation context logged above it), path/by_time (time_s: values [s],
    first, last; viridis), path/by_residual (residual_m: signed values [m] and the scale s of
    the colour map, blue -s .. red +s). Static."""
    xyz = np.asarray(xyz_local_m, dtype=np.float32)
    if fibre is not None:
        stream.log(f"{path}/by_fibre", rr.Points3D(xyz, class_ids=np.asarray(fibre, dtype=np.uint16),
                                                   radii=POINT_RADIUS_UI), static=True)
    if time_s is not None:
        log_coloured(stream, f"{path}/by_time", xyz, *time_s)
    if residual_m is not None:
        values, scale = residual_m
        log_coloured(stream, f"{path}/by_residual", xyz, values, -scale, scale, "RdBu_r")


def log_coloured(stream: rr.RecordingStream, path: str, xyz_local_m: np.ndarray, values: np.ndarray, low: float,
                 high: float, cmap: str = "viridis") -> None:
    """Points [m, local] coloured by values through a matplotlib colour map over [low, high], static."""
    stream.log(path, rr.Points3D(np.asarray(xyz_local_m, dtype=np.float32), colors=value_colors(values, low, high, cmap),
                                 radii=POINT_RADIUS_UI), static=True)


def log_line(stream: rr.RecordingStream, path: str, xyz_local_m: np.ndarray, color, label: str) -> None:
    """A polyline (a trajectory) [m, local], static."""
    stream.log(path, rr.LineStrips3D([np.asarray(xyz_local_m, dtype=np.float32)], colors=[color], labels=[label],
                                     radii=LINE_RADIUS_UI), static=True)


def log_arrows(stream: rr.RecordingStream, path: str, origins_local_m: np.ndarray, vectors_m: np.ndarray, color,
               labels: list[str] | None = None) -> None:
    """Arrows from origins [m, local] along vectors [m], static; labels show on hover."""
    stream.log(path, rr.Arrows3D(origins=np.asarray(origins_local_m, dtype=np.float32),
                                 vectors=np.asarray(vectors_m, dtype=np.float32), colors=[color], labels=labels,
                                 show_labels=False, radii=LINE_RADIUS_UI), static=True)


def log_series(stream: rr.RecordingStream, path: str, timeline: str, index: np.ndarray, values: np.ndarray,
               name: str, color, points: bool = False) -> None:
    """A time series of values over a sequence timeline (iteration, fibre, control ...): a line,
    or markers only when points. NaN values are left out (no line drawn through them)."""
    index, values = np.asarray(index), np.asarray(values, dtype=np.float64)
    keep = np.isfinite(values)
    style = rr.SeriesPoints(names=name, colors=[color], marker_sizes=[3.0]) if points else \
        rr.SeriesLines(names=name, colors=[color], widths=[1.5])
    stream.log(path, style, static=True)
    if keep.any():
        stream.send_columns(path, indexes=[rr.TimeColumn(timeline, sequence=index[keep].astype(np.int64))],
                            columns=rr.Scalars.columns(scalars=values[keep]))


def log_with_sigma(stream: rr.RecordingStream, path: str, timeline: str, values: np.ndarray, sigma: np.ndarray,
                   truth: np.ndarray | None = None) -> None:
    """Estimates over an index (fibre, control) with their 1-sigma band as two lines, and the true
    values when known: path/estimate, path/plus_1sigma, path/minus_1sigma, path/truth."""
    index = np.arange(len(values))
    log_series(stream, f"{path}/estimate", timeline, index, values, "estimate", (30, 110, 220), points=True)
    log_series(stream, f"{path}/plus_1sigma", timeline, index, values + sigma, "+1 sigma", (150, 180, 230))
    log_series(stream, f"{path}/minus_1sigma", timeline, index, values - sigma, "-1 sigma", (150, 180, 230))
    if truth is not None:
        log_series(stream, f"{path}/truth", timeline, index, truth, "truth", (230, 120, 20), points=True)


def log_histogram(stream: rr.RecordingStream, path: str, values: np.ndarray, edges: np.ndarray, color) -> None:
    """A histogram of values over bins `edges` as a bar chart (bars at the bin centres)."""
    counts, _ = np.histogram(values, edges)
    stream.log(path, rr.BarChart(counts.astype(np.float64), abscissa=0.5 * (edges[1:] + edges[:-1]), color=color,
                                 widths=np.diff(edges).astype(np.float32)), static=True)


def eye_over(xyz_local_m: np.ndarray) -> rrb.EyeControls3D:
    """A 3D view's starting camera over points [m, local, z up]: from the south-west, 35 deg above
    the horizon, far enough to take in the bulk of them (2nd-98th percentiles)."""
    low, high = np.percentile(np.asarray(xyz_local_m), [2, 98], axis=0)
    centre, size = 0.5 * (low + high), float(np.max(high - low))
    direction = np.array([-0.55, -0.55, 0.63])  # unit vector, 40 deg elevation
    return rrb.EyeControls3D(position=centre + 1.1 * max(size, 10.0) * direction, look_target=centre,
                             eye_up=[0.0, 0.0, 1.0])


def collapsed_panels(timeline: str) -> tuple:
    """Blueprint panels for a layout that tells its story at once: the blueprint tree and the
    selection panel folded away, the time panel folded to its bar on `timeline`."""
    return (rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(timeline=timeline, state="collapsed"))
