"""deskew_rotation: HDL-64E at 10 Hz turning at 25 deg/s among facades about 50 m away (seed 002).

The head turns 2.5 deg more during a sweep than a static model assumes: 2.19 m at 50 m range.
odometry.csv holds wheel angles and a gyro yaw rate (noiseless by default; pass another OdometrySpec).
"""

from graphcal.simulation.drive import Drive, turn
from graphcal.simulation.scenario import SEED_002_ODOMETRY, OdometrySpec, Scenario
from graphcal.simulation.scene import Facade, Ground, Pole
from graphcal.simulation.script import run_scenario_script

HALF_SIDE_M = 50.0


def scenario(size: float = 1.0, seed: int = 0, yaw_rate_deg_s: float = 25.0, speed_m_s: float = 5.0,
             odometry: OdometrySpec | None = SEED_002_ODOMETRY) -> Scenario:
    """2 s on a circle of radius v / omega in a 100 m square of facades with a ring of poles."""
    h = HALF_SIDE_M
    corners = ((-h, -h), (h, -h), (h, h), (-h, h))
    objects = [Ground(size_m=(2 * h + 20, 2 * h + 20))]
    objects += [Facade(start_xy=corners[k], end_xy=corners[(k + 1) % 4], height_m=15.0, relief_spacing_m=10.0)
                for k in range(4)]
    objects += [Pole(xy=(x, y)) for x in (-30.0, 0.0, 30.0) for y in (-30.0, 30.0)]
    radius = speed_m_s / (yaw_rate_deg_s * 3.141592653589793 / 180.0)
    return Scenario(name="deskew_rotation", sensor_model="HDL-64E", rotation_hz=10.0, duration_s=2.0,
                    size=size, seed=seed, scene=objects, max_range_m=120.0, odometry=odometry,
                    drive=Drive(segments=turn(radius, 2.0 * yaw_rate_deg_s + 10.0), speed_knots=[(0.0, speed_m_s)],
                                start_xy=(0.0, -radius)))


if __name__ == "__main__":
    run_scenario_script(scenario)
