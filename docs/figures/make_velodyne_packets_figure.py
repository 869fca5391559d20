"""Top views of nebula's real VLP-32C and VLS-128 bags imported by graphcal (docs/howto/import-velodyne-packets.md).

Run from the checkout: .venv/bin/python docs/figures/make_velodyne_packets_figure.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graphcal.importers.velodyne_calibration import read_velodyne_calibration  # noqa: E402
from graphcal.importers.velodyne_rosbag import decode_rosbag  # noqa: E402

NEBULA = Path(__file__).resolve().parents[3] / "shared/data/real/nebula_velodyne_rosbag2"
CASES = (("VLP-32C", "vlp32/1713492677464078412", "VLP32.yaml"),
         ("VLS-128", "vls128/1614315746471294674", "VLS128.yaml"))


def main() -> None:
    figure, axes = plt.subplots(1, 2, figsize=(12, 6))
    for axis, (model, bag, calibration) in zip(axes, CASES):
        returns = decode_rosbag(NEBULA / bag, quiet=True).returns
        sensor = read_velodyne_calibration(NEBULA / "calibration" / calibration, model=model).sensor
        keep = np.random.default_rng(0).random(len(returns["range"])) < 200_000 / len(returns["range"])
        xyz = sensor.to_xyz(returns["fibre"][keep].astype(int), returns["range"][keep].astype(np.float64),
                            returns["azimuth"][keep].astype(np.float64))
        near = np.hypot(xyz[:, 0], xyz[:, 1]) < 40
        shown = axis.scatter(xyz[near, 0], xyz[near, 1], c=xyz[near, 2], s=0.2, cmap="viridis", vmin=-3, vmax=3)
        axis.set_title(f"{model}: {len(returns['range']):,} returns, {bag.split('/')[0]} bag (top view)")
        axis.set_xlabel("x [m] (encoder azimuth 0)")
        axis.set_ylabel("y [m]")
        axis.set_aspect("equal")
    figure.colorbar(shown, ax=axes, label="z [m]", shrink=0.8)
    out = Path(__file__).with_name("velodyne_packets_vlp32c_vls128.png")
    figure.savefig(out, dpi=110, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
