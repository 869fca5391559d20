"""Deskew in the viewer: each revolution raw and deskewed in its end-of-scan lidar frame (timeline
"scan"), and every revolution placed in the world with its end-of-scan pose, raw and deskewed.

Entity paths (docs/howto/read-the-report-and-viewer.md):
    /summary                          Markdown: what ran, where files are, colours
    /deskew/{raw,deskewed}            one revolution at a time, L_end frame [m], timeline "scan"
    /world/deskew/{raw,deskewed}      all revolutions at their INS end-of-scan pose, local origin
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from graphcal.viewer.log import POINT_RADIUS_UI, VIEWER_POINTS, collapsed_panels, eye_over
from graphcal.viewer.stream import send_layout

RAW, DESKEWED = (240, 140, 40), (40, 120, 230)


def log_deskew(stream: rr.RecordingStream, raw_scans: Iterable, deskewed_scans: Iterable, n_returns: int,
               trajectory_m: np.ndarray, max_points: int = VIEWER_POINTS) -> tuple[int, np.ndarray | None]:
    """Log the revolutions of two passes over the same recording (graphcal.deskewing.deskew.Scan, in
    order): source "none" and the deskewing source. Every k-th return of each revolution is kept,
    k such that about max_points of the n_returns are shown; trajectory_m (N,3) [m, world]: where
    the vehicle went, with the first revolution it frames the world views' starting camera. Returns (returns shown per cloud, the world
    cloud's local origin [m])."""
    step = max(1, int(np.ceil(n_returns / max_points)))
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    world = {"raw": [], "deskewed": []}
    origin = None
    for raw, deskewed in zip(raw_scans, deskewed_scans):
        if origin is None:
            origin = np.floor(deskewed.position_world_lidar_m)
            first = deskewed.rotation_world_lidar.apply(deskewed.xyz_m[::step]) + deskewed.position_world_lidar_m
            send_layout(stream, deskew_blueprint(eye_over(np.concatenate([first, trajectory_m]) - origin)))
        stream.set_time("scan", sequence=deskewed.index)
        for name, scan, color in (("raw", raw, RAW), ("deskewed", deskewed, DESKEWED)):
            xyz = scan.xyz_m[::step]
            stream.log(f"deskew/{name}", rr.Points3D(xyz.astype(np.float32), colors=[color], radii=POINT_RADIUS_UI))
            world[name].append(scan.rotation_world_lidar.apply(xyz) + scan.position_world_lidar_m - origin)
    stream.reset_time()
    shown = 0
    for name, color in (("raw", RAW), ("deskewed", DESKEWED)):
        if world[name]:
            xyz = np.concatenate(world[name]).astype(np.float32)
            stream.log(f"world/deskew/{name}", rr.Points3D(xyz, colors=[color], radii=POINT_RADIUS_UI), static=True)
            shown = len(xyz)
    return shown, origin


def deskew_summary(recording, source: str, scans: int, shown: int, origin_m: np.ndarray | None, folder: Path) -> str:
    origin = "" if origin_m is None else (f"E {origin_m[0]:.0f} m, N {origin_m[1]:.0f} m, up {origin_m[2]:.0f} m "
                                          f"in {recording.world.crs.to_string()}")
    return "\n".join([
        f"# graphcal deskew: {recording.name}", "",
        f"{len(recording.points):,} returns in {scans} revolutions, motion from **{source}**", "",
        "## Reading the views",
        ("- top left: one revolution in its end-of-scan lidar frame, raw (orange: as measured, the head "
        "assumed still) and deskewed (blue); play the timeline `scan` to go through them"),
        ("- bottom: every revolution placed in the world with its end-of-scan INS pose, raw (left) and deskewed "
        "(right): the raw one is smeared by the motion during each sweep"), "",
        "## Data",
        f"- every k-th return of each revolution: {shown:,} returns per world cloud",
        f"- world positions relative to the local origin {origin} (rerun stores float32)",
        f"- run folder: `{folder}` (one cloud and one 3DTK pose per revolution, poses.csv, deskew.yaml)"])


def deskew_blueprint(eye: rrb.EyeControls3D) -> rrb.Blueprint:
    """One revolution (sensor frame) and the summary on top, the world raw | deskewed below."""
    sensor_eye = rrb.EyeControls3D(position=[-25.0, -25.0, 20.0], look_target=[0.0, 0.0, 0.0], eye_up=[0.0, 0.0, 1.0])
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(rrb.Spatial3DView(origin="/deskew", name="one revolution, L_end frame: raw vs deskewed",
                                             eye_controls=sensor_eye),
                           rrb.TextDocumentView(origin="/summary", name="summary"), column_shares=[3, 2]),
            rrb.Horizontal(*[rrb.Spatial3DView(origin="/world", contents=f"+ /world/deskew/{name}",
                                               name=f"world: {name} revolutions", eye_controls=eye)
                             for name in ("raw", "deskewed")])),
        *collapsed_panels("scan"))
