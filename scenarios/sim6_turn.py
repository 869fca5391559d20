"""sim6_turn: analog of the thesis cloud #6, ground and 4 facades, the vehicle takes a turn.

About 5.5 s and about 4 M returns from an HDL-32E at full size; the recorded trajectory carries
a piecewise-linear position error (knots 1 s apart from the first pose; 0.35 m RMS norm, a
cloud-to-cloud distance to truth of about 13 cm, as seed 001's 13.36 cm), the error seed 001
corrects; heading_error_deg adds a constant INS heading (yaw) error, which only full-pose
trajectory corrections can correct (seed 001's conclusion).

start="section_4_5_2" mounts the head pitched and sets seed 000's joint vs successive start
(graphcal/simulation/starts.py): on this drive the turn makes the lever arm's x and y and the boresight
observable, which sim2_street's straight drive cannot (the vertical lever arm stays unobservable
on flat ground).
"""

from typing import Literal


from graphcal.simulation.drive import Drive, straight, turn
from graphcal.simulation.scenario import ExtrinsicSpec, InsErrors, IntrinsicErrors, Scenario
from graphcal.simulation.scene import Facade, Ground
from graphcal.simulation.script import run_scenario_script
from graphcal.simulation.starts import STARTS

COURTYARD = ((-40.0, -30.0), (40.0, -30.0), (40.0, 30.0), (-40.0, 30.0))


def scenario(size: float = 1.0, seed: int = 0, piecewise_error_m: float = 0.35,
             heading_error_deg: float = 0.0, start: Literal["nominal", "table_4_1", "section_4_5_2"] = "nominal") -> Scenario:
    """Straight 15 m, a 90 deg left turn of radius 12 m, straight 15 m, at 8 m/s, in a courtyard."""
    if start not in ("nominal", *STARTS):
        raise ValueError(f"start must be nominal or one of {', '.join(STARTS)}, not {start!r}")
    extrinsic, intrinsic_errors = STARTS[start] if start != "nominal" else (ExtrinsicSpec(), IntrinsicErrors())
    corners = COURTYARD
    facades = [Facade(start_xy=corners[k], end_xy=corners[(k + 1) % 4], height_m=15.0) for k in range(4)]
    return Scenario(name="sim6_turn", sensor_model="HDL-32E", duration_s=5.7, size=size, seed=seed,
                    scene=[Ground(size_m=(100.0, 80.0))] + facades,
                    drive=Drive(segments=straight(15.0) + turn(12.0, 90.0) + straight(20.0),
                                speed_knots=[(0.0, 8.0)], start_xy=(-20.0, -20.0)),
                    extrinsic=extrinsic, intrinsic_errors=intrinsic_errors,
                    ins=InsErrors(piecewise_error_m=piecewise_error_m, piecewise_interval_s=1.0),
                    effects={"heading_bias": {"bias_deg": heading_error_deg}} if heading_error_deg else {})


if __name__ == "__main__":
    run_scenario_script(scenario)
