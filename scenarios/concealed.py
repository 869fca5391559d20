"""concealed: the sim6_turn courtyard drive with one (or more) left-out effects, each small against
the 1 cm range noise and absorbed in part by ordinary calibration parameters, for the mismatch
finder (graphcal.diagnose). The nominal model the finder compares with has none of them.

The head is pitched 20 deg as mobile mapping mounts it (PITCHED_HEAD). Level, in this flat
courtyard, the fibres that see only the ground can rise together unseen and the joint baseline
slides into the fibres' collapse (docs/reference/math.md); its drift also showed as a false range scale of
~400 ppm on clean recordings and hid projection_scale and fibre_horizontal_offset.

CONCEALED[effect] gives the effect's parameters, the calibration mode whose parameters absorb it,
and how. The intrinsics and extrinsic are exact and the INS error-free apart from the effect, so that
each test is about the effect alone; `effect=None` is the clean recording (no false alarm expected).
"""

from dataclasses import dataclass

import numpy as np
from pyproj import CRS

from graphcal.recording.geodesy import grid_to_geodetic, map_factors
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.script import load_scenario_builder, run_scenario_script
from graphcal.simulation.starts import PITCHED_HEAD

CRS_NAME = "EPSG:32631"
# 288 km west of the zone's central meridian at 48.8 N: grid scale factor k = 1.00102
ORIGIN_M = (160000.0, 5411000.0, 50.0)


def grid_scale_minus_one(crs: str = CRS_NAME, origin_m=ORIGIN_M) -> float:
    """k - 1 of the map projection at the scenario's origin (pyproj)."""
    lat, lon, _ = grid_to_geodetic(CRS.from_user_input(crs), np.array([origin_m], dtype=np.float64))[0]
    return float(map_factors(CRS.from_user_input(crs), lon, lat)[0] - 1.0)


@dataclass(frozen=True)
class Concealment:
    """An effect's simulator parameters, the true headline magnitude (diagnosis.json units), the
    calibration mode of the nominal model, and what absorbs it there."""

    effects: dict
    magnitude: float
    mode: str
    absorbed_by: str
    lever_arm_error_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


CONCEALED = {
    "time_offset": Concealment({"time_offset": {"offset_s": 0.005}}, 0.005, "joint",
                               "the lever arm along x: at constant speed a latency is a fixed shift along the track"),
    "range_scale": Concealment({"range_scale": {"scale": 1e-3}}, 1e-3, "joint",
                               "per-fibre range offsets, which equal the scale at mid range"),
    "incidence_range_bias": Concealment({"incidence_range_bias": {"bias_m": 0.03}}, 0.03, "joint",
                                        "per-fibre range offsets and elevations: over the drive each fibre "
                                        "sees the road at a narrow span of incidences"),
    "azimuth_eccentricity": Concealment({"azimuth_eccentricity": {"amplitude_deg": 0.08, "phase_deg": 30.0}}, 0.08,
                                        "joint", "per-fibre azimuth offsets and the boresight yaw (its mean)"),
    "heading_drift": Concealment({"heading_drift": {"rate_deg_s": 0.01}}, 0.01, "joint",
                                 "the boresight yaw (its mean over the drive)"),
    "spin_rate": Concealment({"spin_rate": {"error": 0.03}}, 0.03, "joint",
                             "the lever arm along x (the mean time error over the revolution)"),
    "intra_sweep_motion": Concealment({"intra_sweep_motion": {"stamp": "revolution"}}, 1.0, "joint",
                                      "the lever arm along x (half a revolution of travel on average)"),
    "projection_scale": Concealment({"projection_scale": {"scale": grid_scale_minus_one()}}, grid_scale_minus_one(),
                                    "joint", "the lever arm and range offsets (a scale of the trajectory)"),
    "fibre_horizontal_offset": Concealment({"fibre_horizontal_offset": {"offset_m": 0.02}}, 0.02, "joint",
                                           "per-fibre azimuth offsets, which equal it at one range"),
    "lever_arm": Concealment({}, float(np.linalg.norm((0.06, 0.04, 0.0))), "intrinsic",
                             "nothing estimated holds it: the intrinsic model keeps the nominal extrinsic",
                             lever_arm_error_m=(0.06, 0.04, 0.0)),
    "heading_bias": Concealment({"heading_bias": {"bias_deg": 0.1}}, 0.1, "joint",
                                "the boresight yaw, entirely on a level drive (not separable)"),
}


def scenario(size: float = 1.0, seed: int = 0, effect: str | None = "time_offset",
             effects: tuple[str, ...] = ()) -> Scenario:
    """sim6_turn, pitched head, with range noise 1 cm, exact calibration and INS, and the left-out effect(s) of CONCEALED
    (effect, plus any in `effects`; None and () for a clean recording)."""
    chosen = ((effect,) if effect else ()) + tuple(effects)
    unknown = sorted(set(chosen) - set(CONCEALED))
    if unknown:
        raise ValueError(f"unknown concealed effect(s) {unknown}; known: {', '.join(CONCEALED)}")
    spec, lever_arm = {}, np.zeros(3)
    for name in chosen:
        spec.update(CONCEALED[name].effects)
        lever_arm += CONCEALED[name].lever_arm_error_m
    base = load_scenario_builder("sim6_turn")(size=size, seed=seed, piecewise_error_m=0.0)
    return base.model_copy(update={"name": "concealed-" + ("+".join(chosen) or "clean"), "range_noise_m": 0.01,
                                   "effects": spec, "crs": CRS_NAME, "origin_m": ORIGIN_M,
                                   "extrinsic": PITCHED_HEAD.model_copy(update={"error_lever_arm_m": tuple(lever_arm)})})


if __name__ == "__main__":
    run_scenario_script(scenario)
