"""Benchmark: smoothing a trajectory's white noise (graphcal.recording.trajectory_noise.smoothed_poses) on drives
of 1, 2, 5 and 10 minutes of 200 Hz poses: a seeded synthetic drive (speed changes, a smooth turn every 20 s, the
body's pitch and roll from the accelerations) with 5 mm and 0.005 deg white noise a sample. Figures per drive:
seconds, peak memory, poses per second, and the RMS of what is left of the noise after smoothing (position per
axis [mm], attitude [deg]) against the clean drive. Each drive runs in its own process. Prints them and writes
benchmarks/results/trajectory_noise.json.
"""

from __future__ import annotations

import argparse
import datetime
import time
from pathlib import Path

from common import machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _case(minutes: float, seed: int, queue) -> None:
    import numpy as np
    from scipy.spatial.transform import Rotation

    from graphcal.recording.poses import PoseTrack
    from graphcal.recording.trajectory_noise import smoothed_poses

    rng = np.random.default_rng(seed)
    rate_hz = 200.0
    t = 345600.0 + np.arange(0.0, 60.0 * minutes, 1.0 / rate_hz)
    seconds = t - t[0]
    yaw_rate = 0.45 * np.sin(2 * np.pi * seconds / 40.0) ** 8  # rad/s: a smooth turn every 20 s
    yaw = np.cumsum(yaw_rate) / rate_hz
    speed = 7.0 + 2.0 * np.sin(2 * np.pi * seconds / 30.0)
    position = np.column_stack([np.cumsum(speed * np.cos(yaw)) / rate_hz, np.cumsum(speed * np.sin(yaw)) / rate_hz,
                                0.5 * np.sin(2 * np.pi * seconds / 90.0)])
    body_rad_per_ms2 = np.radians(0.5)  # the suspension's roll and pitch per m/s2 of acceleration
    rpy = np.column_stack([body_rad_per_ms2 * yaw_rate * speed, body_rad_per_ms2 * np.gradient(speed, seconds), yaw])
    clean = Rotation.from_euler("xyz", rpy)
    noisy = PoseTrack(t, position + rng.normal(0, 0.005, position.shape),
                      clean * Rotation.from_rotvec(rng.normal(0, np.radians(0.005), position.shape)))
    started = time.perf_counter()
    smoothed, noise = smoothed_poses(noisy)
    elapsed = time.perf_counter() - started
    left_m = smoothed.position_m - position
    left_rad = (clean.inv() * smoothed.rotation).magnitude()
    queue.put({"poses": len(t), "seconds": round(elapsed, 2), "peak_gib": round(peak_gib(), 2),
               "poses_per_s": round(len(t) / elapsed), "measured_noise_mm": round(noise.position_m * 1e3, 2),
               "left_position_rms_mm": round(float(np.sqrt(np.mean(left_m ** 2))) * 1e3, 2),
               "left_attitude_rms_deg": round(float(np.degrees(np.sqrt(np.mean(left_rad ** 2)))), 5)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, nargs="+", default=[1.0, 2.0, 5.0, 10.0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--result", type=Path, default=RESULTS / "trajectory_noise.json")
    args = parser.parse_args()
    figures = {"machine": machine(),
               "date": datetime.date.today().isoformat(),
               "drives": {f"{m:g} min": run_in_process(_case, m, args.seed) for m in args.minutes}}
    report(figures, args.result)


if __name__ == "__main__":
    main()
