"""sim2_street: analog of the thesis cloud #2, a street with facades seen by an HDL-32E.

start="table_4_1" (default): intrinsic errors on every fibre but the reference (15), within
+-3 deg for the angles and +-10 cm for range and Hz, with the RMS of Table 4.1 (10 cm, 2.5 deg,
3 deg, 10 cm); the extrinsic is exact. start="section_4_5_2": the start of seed 000's joint vs
successive comparison: extrinsic off by 50/50/80 cm and 2.5/3/-2 deg (roll/pitch/yaw),
intrinsics off by an RMS of 3 cm (range, Hz) and 0.3 deg (angles).

The head is pitched 20 deg forward (spin axis tilted towards the driving direction), as mobile
mapping systems mount it: every fibre then sweeps the road and the facades over a span of
ranges. Level, each fibre sees the flat road at one range only, and the azimuth offsets of the
lowest fibres (which see nothing but road) are unobservable; graphcal reports them so.
Facades carry pilasters and two ledges (3.5 m, 7 m) whose horizontal faces the upward fibres see.
"""

from typing import Literal

from graphcal.sim.drive import Drive, straight
from graphcal.sim.scenario import ExtrinsicSpec, IntrinsicErrors, Scenario
from graphcal.sim.scene import ParkedCar, Pole, street
from graphcal.sim.script import run_scenario_script

TABLE_4_1_ERRORS = IntrinsicErrors(range_m=0.10, azimuth_deg=3.0, elevation_deg=3.0, h_z_m=0.10,
                                   rms=(0.10, 2.5, 3.0, 0.10))

PITCHED_HEAD = ExtrinsicSpec(lever_arm_m=(0.8, 0.0, 1.9), boresight_deg=(20.0, 0.0, 90.0))

SECTION_4_5_2_ERRORS = IntrinsicErrors(range_m=0.05, azimuth_deg=0.5, elevation_deg=0.5, h_z_m=0.05,
                                       rms=(0.03, 0.3, 0.3, 0.03))
SECTION_4_5_2_HEAD = PITCHED_HEAD.model_copy(update={"error_lever_arm_m": (0.5, 0.5, 0.8),
                                                      "error_boresight_deg": (2.5, 3.0, -2.0)})
STARTS = {"table_4_1": (PITCHED_HEAD, TABLE_4_1_ERRORS), "section_4_5_2": (SECTION_4_5_2_HEAD, SECTION_4_5_2_ERRORS)}


def scenario(size: float = 1.0, seed: int = 0, range_noise_m: float = 0.0,
             start: Literal["table_4_1", "section_4_5_2"] = "table_4_1") -> Scenario:
    """A 6 s drive at 6 m/s down a 16 m wide street with pilastered facades, poles and cars."""
    objects = street(length_m=90.0, width_m=16.0, height_m=12.0, relief_spacing_m=5.0, start_x_m=-25.0,
                     ledge_heights_m=(3.5, 7.0))
    objects += [Pole(xy=(x, side * 6.0)) for x in (-10.0, 5.0, 20.0, 35.0) for side in (-1, 1)]
    objects += [ParkedCar(xy=(x, side * 5.5), yaw_deg=0.0) for x, side in ((0.0, 1), (12.0, -1), (28.0, 1))]
    if start not in STARTS:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, not {start!r}")
    extrinsic, intrinsic_errors = STARTS[start]
    return Scenario(name="sim2_street", sensor_model="HDL-32E", duration_s=6.0, size=size, seed=seed,
                    scene=objects, drive=Drive(segments=straight(60.0), speed_knots=[(0.0, 6.0)]),
                    extrinsic=extrinsic, intrinsic_errors=intrinsic_errors, range_noise_m=range_noise_m)


if __name__ == "__main__":
    run_scenario_script(scenario)
