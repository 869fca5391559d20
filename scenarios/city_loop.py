"""city_loop: a drive of any length through a procedural city district, passing its streets again and again.

The district (graphcal/simulation/district.py), drawn from the seed: a grid of blocks (2 x 2 of 40 m by
default, streets 16 m between facades), each side a row of 2-4 buildings of their own height (6-22 m) with
pilasters and ledges, kerbed sidewalks, bollards at the crossings, street lights, parked cars, trees and
boxes; a ring of buildings faces the outer streets. About 300 objects and 20,000 triangles at 2 x 2: open3d's
raycasting (a BVH) costs about as much per ray for 250 triangles as for 400,000, so every chunk casts
against the whole district (0.02 s for 170,000 rays either way).

The route (graphcal/simulation/route.py): a circuit over the crossings that drives every street once in each
direction without a U-turn (left and right turns of 6 m radius, straight on at some crossings), looped for
as long as the drive lasts: a cruise speed drawn for each straight (6-12 m/s), 4 m/s through the turns, a
stop of 2-6 s before some of them (about 6 m/s on average). A lap of the default district is about 1,300 m,
3.5 to 4 minutes: beyond a lap every street has been passed twice, once each way; beyond two, twice in the
same direction too. A minute already passes a street or two both ways.

The true sensor is off the nominal one as in sim2_street (`start`: graphcal/simulation/starts.py, the head
pitched 20 deg). The recorded INS drifts as a GNSS-aided one does (CITY_INS): a position random walk of
5 mm/sqrt(s) and a 2 cm slow bias (60 s correlation) make a few cm over tens of seconds, the heading walks
by 0.002 deg/sqrt(s), and a GNSS-like jump of about 3 cm per axis comes every 30 s on average.

traffic=True (--traffic) adds moving traffic (CITY_TRAFFIC, graphcal/simulation/traffic.py's
DistrictTrafficSpec, drawn from the seed): vehicles overtaking, oncoming and crossing the drive's street, each
driving its own way through the grid, pedestrians on the pavements and crossing; traffic_density
(--traffic-density) times 80 vehicles and 60 pedestrians a minute. About a fifth of the returns land on them at
density 1 (truth/points.parquet's `moving`). Without traffic (the default) nothing moves.

`python scenarios/city_loop.py --duration 600 --size 0.1` writes the recording as it simulates
(simulate_to: memory stays flat whatever the duration; the traffic's movers, about 14 kB per second of drive,
are held whole like the trajectories).
"""

from typing import Literal

import numpy as np

from graphcal.simulation.district import KERB_M, DistrictLayout, district
from graphcal.simulation.route import circuit_path, looped_drive, street_circuit
from graphcal.simulation.scenario import InsErrors, Scenario
from graphcal.simulation.script import run_scenario_script
from graphcal.simulation.starts import STARTS
from graphcal.simulation.traffic import DistrictTrafficSpec

TURN_RADIUS_M = 6.0
CITY_INS = InsErrors(position_walk_m_sqrt_s=0.005, heading_walk_deg_sqrt_s=0.002, position_bias_m=0.02,
                     bias_correlation_s=60.0, jump_rate_hz=1 / 30, jump_m=0.03)
CITY_TRAFFIC = DistrictTrafficSpec()  # the movers per minute of drive at traffic_density 1


def scenario(duration_s: float = 60.0, size: float = 1.0, seed: int = 0, blocks: tuple[int, int] = (2, 2),
             range_noise_m: float = 0.0, start: Literal["table_4_1", "section_4_5_2"] = "table_4_1",
             traffic: bool = False, traffic_density: float = 1.0) -> Scenario:
    """A drive of duration_s seconds looping over the streets of a procedural district of blocks (n_x, n_y), with
    moving vehicles and pedestrians when traffic (traffic_density times CITY_TRAFFIC's per minute)."""
    if start not in STARTS:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, not {start!r}")
    extrinsic, intrinsic_errors = STARTS[start]
    scene_rng, route_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    layout = DistrictLayout(n_x=blocks[0], n_y=blocks[1])
    lap, start_xy, start_yaw_deg = circuit_path(street_circuit(*blocks, route_rng), layout.pitch_m, TURN_RADIUS_M)
    return Scenario(name="city_loop", sensor_model="HDL-32E", duration_s=duration_s, size=size, seed=seed,
                    scene=district(layout, scene_rng),
                    drive=looped_drive(lap, start_xy, start_yaw_deg, duration_s, route_rng),
                    extrinsic=extrinsic, intrinsic_errors=intrinsic_errors, range_noise_m=range_noise_m,
                    ins=CITY_INS, traffic=city_traffic(layout, seed, traffic_density) if traffic else None)


def city_traffic(layout: DistrictLayout, seed: int, density: float) -> DistrictTrafficSpec:
    """CITY_TRAFFIC on the district's streets, density times as many movers per minute, drawn from seed: the grid's,
    pedestrians walking 0.7 m from the facades' line (between the relief, at most 0.45 m deep, and the street
    furniture, within 2 m of the kerb) on the pavements' height, crossing 1.5 m beyond the crossings (street
    furniture and parked cars keep 3 m beyond them)."""
    if density < 0:
        raise ValueError(f"traffic_density must be >= 0, not {density:g}")
    return CITY_TRAFFIC.model_copy(update={
        "blocks": (layout.n_x, layout.n_y), "pitch_m": layout.pitch_m, "seed": seed, "pavement_z_m": KERB_M,
        "sidewalk_offset_m": layout.street_m / 2 - 0.7, "crosswalk_m": layout.street_m / 2 + 1.5,
        "vehicles_per_min": CITY_TRAFFIC.vehicles_per_min * density,
        "pedestrians_per_min": CITY_TRAFFIC.pedestrians_per_min * density})


if __name__ == "__main__":
    run_scenario_script(scenario)
