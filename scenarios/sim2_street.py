"""sim2_street: analog of the thesis cloud #2, a street with facades seen by an HDL-32E.

start="table_4_1" (default): intrinsic errors with the RMS of Table 4.1, exact extrinsic;
start="section_4_5_2": the start of seed 000's joint vs successive comparison (both in
graphcal/simulation/starts.py). On this straight drive the lever arm and the roll about the driving
line are unobservable; sim6_turn with the same start has a turn that shows them.

The head is pitched 20 deg forward (spin axis tilted towards the driving direction), as mobile
mapping systems mount it: every fibre then sweeps the road and the facades over a span of
ranges. Level, each fibre sees the flat road at one range only, and the azimuth offsets of the
lowest fibres (which see nothing but road) are unobservable; graphcal reports them so.
Facades carry pilasters and two ledges (3.5 m, 7 m) whose horizontal faces the upward fibres see.

traffic=True adds moving traffic (graphcal/simulation/traffic.py, STREET_TRAFFIC): cars overtaking and
oncoming 2 m either side of the street's axis, pedestrians on the sidewalks and crossing, drawn from the
seed; about 17 % of the returns land on them (scenarios/street_traffic.py is this street with traffic).
"""

from typing import Literal

from graphcal.simulation.drive import Drive, straight
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.scene import ParkedCar, Pole, street
from graphcal.simulation.script import run_scenario_script
from graphcal.simulation.starts import STARTS
from graphcal.simulation.traffic import TrafficSpec

STREET_TRAFFIC = TrafficSpec(vehicles=6, pedestrians=12, street_start_xy=(-25.0, 0.0), street_end_xy=(65.0, 0.0))


def scenario(size: float = 1.0, seed: int = 0, range_noise_m: float = 0.0,
             start: Literal["table_4_1", "section_4_5_2"] = "table_4_1", traffic: bool = False) -> Scenario:
    """A 6 s drive at 6 m/s down a 16 m wide street with pilastered facades, poles and cars (and moving
    traffic, drawn from the seed, with traffic=True)."""
    objects = street(length_m=90.0, width_m=16.0, height_m=12.0, relief_spacing_m=5.0, start_x_m=-25.0,
                     ledge_heights_m=(3.5, 7.0))
    objects += [Pole(xy=(x, side * 6.0)) for x in (-10.0, 5.0, 20.0, 35.0) for side in (-1, 1)]
    objects += [ParkedCar(xy=(x, side * 5.5), yaw_deg=0.0) for x, side in ((0.0, 1), (12.0, -1), (28.0, 1))]
    if start not in STARTS:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, not {start!r}")
    extrinsic, intrinsic_errors = STARTS[start]
    return Scenario(name="sim2_street", sensor_model="HDL-32E", duration_s=6.0, size=size, seed=seed,
                    scene=objects, drive=Drive(segments=straight(60.0), speed_knots=[(0.0, 6.0)]),
                    extrinsic=extrinsic, intrinsic_errors=intrinsic_errors, range_noise_m=range_noise_m,
                    traffic=STREET_TRAFFIC.model_copy(update={"seed": seed}) if traffic else None)


if __name__ == "__main__":
    run_scenario_script(scenario)
