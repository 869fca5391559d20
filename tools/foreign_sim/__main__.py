"""python -m tools.foreign_sim FAMILY --out DIR [options]"""

from __future__ import annotations

import argparse
import sys
import time

from tools.foreign_sim.departures import Departures
from tools.foreign_sim.scenes import FAMILIES
from tools.foreign_sim.simulation import simulate


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.foreign_sim",
                                     description="Write a simulated lidar drive (graphcal-recording/1) "
                                                 "independently of graphcal's simulator.")
    parser.add_argument("family", choices=FAMILIES)
    parser.add_argument("--out", required=True, help="recording directory to write (replaced if it is a recording)")
    parser.add_argument("--duration", type=float, default=15.0, help="drive duration [s] (default 15)")
    parser.add_argument("--size", type=float, default=1.0, help="fraction of firing blocks kept, in (0, 1]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mount", choices=("level", "tilted"), default="level")
    parser.add_argument("--range-noise", type=float, default=0.01, help="range noise sigma [m]")
    parser.add_argument("--intrinsic-bounds", type=float, nargs=4, default=(0.03, 0.3, 0.3, 0.03),
                        metavar=("D_RANGE_M", "D_AZIMUTH_DEG", "D_ELEVATION_DEG", "H_Z_M"),
                        help="true per-fibre offsets drawn uniformly within +- these (default 0.03 0.3 0.3 0.03)")
    parser.add_argument("--extrinsic-lever", type=float, default=0.05, help="lever-arm error bound per axis [m]")
    parser.add_argument("--extrinsic-angle", type=float, default=0.5, help="boresight error bound per axis [deg]")
    parser.add_argument("--ins-noise-m", type=float, default=0.005, help="INS white position noise [m]")
    parser.add_argument("--ins-noise-deg", type=float, default=0.005, help="INS white attitude noise [deg]")
    parser.add_argument("--ins-drift", type=float, default=0.0, help="peak slow INS position drift [m] (default off)")
    parser.add_argument("--ins-drift-deg", type=float, default=0.0,
                        help="peak slow INS attitude drift [deg] (default off)")
    parser.add_argument("--ins-rate", type=float, default=200.0, help="INS rate [Hz], a divisor of 1000")
    parser.add_argument("--encoder-jitter", type=float, default=0.002, help="per-revolution encoder error RMS [deg]")
    parser.add_argument("--spin-wander", type=float, default=0.5, help="spin-rate wander around 600 rpm [rpm]")
    departures = parser.add_argument_group("departures from the contract's model (truth/effects.yaml; default off)")
    departures.add_argument("--range-scale", type=float, default=0.0, help="measured / true distance - 1")
    departures.add_argument("--incidence-range-bias", type=float, default=0.0,
                            help="distance read long at grazing incidence, x (1 - cos incidence) [m]")
    departures.add_argument("--eccentricity", type=float, default=0.0,
                            help="encoder eccentricity: the reading lags the head by this x sin(angle + phase) [deg]")
    departures.add_argument("--eccentricity-phase", type=float, default=0.0, help="its phase [deg]")
    departures.add_argument("--latency", type=float, default=0.0, help="stamps after the firing by this [s]")
    departures.add_argument("--heading-drift", type=float, default=0.0, help="INS yaw drift [deg/s]")
    departures.add_argument("--revolution-stamps", action="store_true",
                            help="stamp every return with its revolution's start, not its firing time")
    parser.add_argument("--name", default=None, help="recording name (default foreign-FAMILY-sSEED)")
    parser.add_argument("--verbose", "-v", action="store_true", help="print progress on stderr")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    try:
        chosen = Departures(range_scale=args.range_scale, incidence_range_bias_m=args.incidence_range_bias,
                            eccentricity_deg=args.eccentricity, eccentricity_phase_deg=args.eccentricity_phase,
                            latency_s=args.latency, heading_drift_deg_s=args.heading_drift,
                            revolution_stamps=args.revolution_stamps)
        path = simulate(args.family, args.out, duration_s=args.duration, size=args.size, seed=args.seed,
                        mount=args.mount, range_noise_m=args.range_noise, intrinsic_bounds=tuple(args.intrinsic_bounds),
                        extrinsic_lever_m=args.extrinsic_lever, extrinsic_angle_deg=args.extrinsic_angle,
                        ins_noise_m=args.ins_noise_m, ins_noise_deg=args.ins_noise_deg, ins_drift_m=args.ins_drift,
                        ins_drift_deg=args.ins_drift_deg, ins_rate_hz=args.ins_rate,
                        encoder_jitter_deg=args.encoder_jitter, spin_wander_rpm=args.spin_wander, departures=chosen,
                        name=args.name, verbose=args.verbose)
    except (ValueError, FileExistsError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.verbose:
        print(f"wrote {path} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
