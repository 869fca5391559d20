"""deskew_linear: HDL-64E at 10 Hz driving straight at 10 m/s down a street (seed 002).

One revolution lasts 0.1 s, so the vehicle moves 1 m during a sweep (1.38 m at 50 km/h). odometry.csv
holds wheel angles and a gyro yaw rate (noiseless by default; pass another OdometrySpec).
"""

from graphcal.simulation.drive import Drive, straight
from graphcal.simulation.scenario import SEED_002_ODOMETRY, OdometrySpec, Scenario
from graphcal.simulation.scene import ParkedCar, Pole, street
from graphcal.simulation.script import run_scenario_script


def scenario(size: float = 1.0, seed: int = 0, speed_m_s: float = 10.0,
             odometry: OdometrySpec | None = SEED_002_ODOMETRY) -> Scenario:
    """2 s at constant speed in a 20 m wide street with poles and parked cars."""
    objects = street(length_m=120.0, width_m=20.0, height_m=12.0, relief_spacing_m=8.0, start_x_m=-30.0)
    objects += [Pole(xy=(x, side * 8.0)) for x in range(-20, 90, 15) for side in (-1, 1)]
    objects += [ParkedCar(xy=(x, -7.0)) for x in (5.0, 25.0, 45.0)]
    return Scenario(name="deskew_linear", sensor_model="HDL-64E", rotation_hz=10.0, duration_s=2.0,
                    size=size, seed=seed, scene=objects, max_range_m=120.0, odometry=odometry,
                    drive=Drive(segments=straight(2.0 * speed_m_s + 5.0), speed_knots=[(0.0, speed_m_s)]))


if __name__ == "__main__":
    run_scenario_script(scenario)
