"""street_traffic: sim2_street with moving traffic, cars overtaking and oncoming, pedestrians walking and crossing.

The street, the drive and the sensor's errors are sim2_street's (same seed, same draws); the traffic
(sim2_street.STREET_TRAFFIC, graphcal/simulation/traffic.py) is drawn from the seed too. About 17 % of
the returns land on moving objects; truth/points.parquet flags them (column `moving`).
"""

from typing import Literal

from graphcal.simulation.scenario import Scenario
from graphcal.simulation.script import load_scenario_builder, run_scenario_script


def scenario(size: float = 1.0, seed: int = 0, range_noise_m: float = 0.0,
             start: Literal["table_4_1", "section_4_5_2"] = "table_4_1") -> Scenario:
    """sim2_street's 6 s drive with moving cars and pedestrians."""
    street = load_scenario_builder("sim2_street")(size=size, seed=seed, range_noise_m=range_noise_m, start=start,
                                                  traffic=True)
    return street.model_copy(update={"name": "street_traffic"})


if __name__ == "__main__":
    run_scenario_script(scenario)
