"""docs/figures/ouster_os1_top_view.png: top view of the real OS-1-128 capture of ouster-sdk, imported.

One frame (the second of three) of OS-1-128_v2.3.0_1024x10_lb_n3.pcap, imported with its metadata
JSON by graphcal.importers.ouster_pcap, turned into points with the recording's own sensor model
and extrinsic (body = Ouster sensor frame: x forward, y left), coloured by reflectivity; the
beam origins (15.8 mm from the axis) are drawn at the centre.

    .venv/bin/python docs/figures/make_ouster_figure.py [FOLDER_OF_THE_CAPTURES]

Matplotlib (Agg), deterministic.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graphcal.importers.ouster_metadata import read_ouster_metadata  # noqa: E402
from graphcal.importers.ouster_pcap import import_ouster  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT = HERE.parents[2] / "shared/data/real/ouster_sdk_pcaps"
EXTENT_M = 30.0


def main(folder: Path) -> Path:
    metadata = read_ouster_metadata(folder / "OS-1-128_v2.3.0_1024x10.json")
    with tempfile.TemporaryDirectory() as scratch:
        recording = import_ouster(folder / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap", metadata, Path(scratch) / "os1",
                                  position=(0.0, 0.0, 0.0), quiet=True)
        points = recording.points.read()
    frame = points["scan"] == 1
    fibre = points["fibre"][frame].astype(np.intp)
    p_lidar = recording.sensor.to_xyz(fibre, points["range"][frame].astype(np.float64),
                                      points["azimuth"][frame].astype(np.float64))
    p = recording.extrinsic.lidar_to_body(p_lidar)
    near = np.all(np.abs(p[:, :2]) < EXTENT_M, axis=1)
    fig, (whole, centre) = plt.subplots(1, 2, figsize=(12, 6), gridspec_kw={"width_ratios": [2, 1]})
    dots = whole.scatter(p[near, 0], p[near, 1], c=points["intensity"][frame][near], s=0.2, cmap="viridis",
                         vmin=0, vmax=np.percentile(points["intensity"][frame], 99), rasterized=True)
    whole.set(xlim=(-EXTENT_M, EXTENT_M), ylim=(-EXTENT_M, EXTENT_M), aspect="equal", xlabel="x [m] (sensor frame)",
              ylabel="y [m]", title=f"OS-1-128, one frame: {int(frame.sum()):,} returns (|x|, |y| < {EXTENT_M:g} m shown)")
    fig.colorbar(dots, ax=whole, label="reflectivity", shrink=0.8)
    # the beam origins: B (cos theta, -sin theta, 0) in the lidar frame, one circle of radius B
    theta = np.linspace(0, 2 * np.pi, 361)
    B = recording.sensor.beam_origin_m
    ring = recording.extrinsic.lidar_to_body(np.column_stack([B * np.cos(theta), -B * np.sin(theta), 0 * theta]))
    centre.plot(ring[:, 0] * 1000, ring[:, 1] * 1000, color="tab:red", label=f"beam origins ({B * 1000:.1f} mm)")
    first = recording.extrinsic.lidar_to_body(np.array([[B, 0.0, 0.0]]))[0] * 1000
    centre.plot(*first[:2], "o", color="tab:red", label="beam origin at encoder 0 (lidar x)")
    centre.plot(0, 0, "k+", ms=12, label="spin axis")
    centre.set(aspect="equal", xlim=(-25, 25), ylim=(-25, 25), xlabel="x [mm]", ylabel="y [mm]", title="centre")
    centre.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    out = HERE / "ouster_os1_top_view.png"
    fig.savefig(out, dpi=90)
    return out


if __name__ == "__main__":
    print(main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT))
