"""An independent lidar drive simulator: recordings (RECORDING.md, graphcal-recording/1) whose
scenes, vehicle dynamics, firing pattern and raycasting graphcal's own simulator did not shape.

It imports nothing from graphcal or factors. Use:

    from tools.foreign_sim import Departures, simulate, FAMILIES
    simulate("relief_street", "out/relief", duration_s=15.0, size=0.1, seed=3)
    simulate("box_street", "out/latency", size=0.1, departures=Departures(latency_s=0.008))
    simulate("box_street", "out/far", size=0.1, **WIDEST_FACTORY_ERRORS)

or `python -m tools.foreign_sim relief_street --out out/relief --size 0.1`.
"""

from tools.foreign_sim.departures import Departures
from tools.foreign_sim.scenes import FAMILIES
from tools.foreign_sim.simulation import WIDEST_FACTORY_ERRORS, simulate

__all__ = ["FAMILIES", "WIDEST_FACTORY_ERRORS", "Departures", "simulate"]
