"""A route over a grid of streets: a closed circuit that drives every street once each way, and its speeds.

Streets run along the lines of a grid of (n_x + 1) x (n_y + 1) crossings, pitch_m apart, crossing
(i, j) at local (i pitch_m, j pitch_m) (x east, y north, m). The circuit never turns back on itself
(no U-turn): at each crossing it goes straight, left or right. Speeds: a random cruise on each
straight, slowing for each turn, now and then a stop before one (a red light); every draw seeded.
"""

from __future__ import annotations

import itertools

import numpy as np

from graphcal.common.errors import ConfigError
from graphcal.simulation.drive import Arc, Drive, Straight

Node = tuple[int, int]
_MAX_TRIALS = 20_000  # transition changes tried before giving up on a single circuit


def street_circuit(n_x: int, n_y: int, rng: np.random.Generator) -> list[Node]:
    """Crossings of a closed walk (the first not repeated at the end) that takes every street of an
    n_x x n_y grid of blocks exactly once in each direction, without a U-turn.

    Starts from the face tracing (at every crossing turn right: one loop per block, one around the
    outside) and changes the crossings' transitions at random while the number of loops does not grow,
    until one loop is left.
    """
    if min(n_x, n_y) < 2:
        raise ConfigError("a street circuit needs at least 2 x 2 blocks (a crossing of four streets)")
    neighbours = {(i, j): [(i + di, j + dj) for di, dj in ((1, 0), (0, 1), (-1, 0), (0, -1))
                           if 0 <= i + di <= n_x and 0 <= j + dj <= n_y]
                  for i in range(n_x + 1) for j in range(n_y + 1)}
    # transition[v][u] = w: arriving at v from u, leave towards w; face tracing: the next neighbour clockwise
    transition = {v: {u: around[(k - 1) % len(around)] for k, u in enumerate(around)}
                  for v, around in neighbours.items()}
    choices = {v: _derangements(around) for v, around in neighbours.items() if len(around) > 2}
    crossings = sorted(choices)
    loops = _loops(transition)
    for _ in range(_MAX_TRIALS):
        if len(loops) == 1:
            return [edge[0] for edge in loops[0]]
        v = crossings[rng.integers(len(crossings))]
        previous = transition[v]
        transition[v] = choices[v][rng.integers(len(choices[v]))]
        trial = _loops(transition)
        if len(trial) <= len(loops):
            loops = trial
        else:
            transition[v] = previous
    raise ConfigError(f"no single street circuit found on {n_x} x {n_y} blocks")


def _derangements(around: list[Node]) -> list[dict[Node, Node]]:
    """Every transition table at a crossing that sends no arrival back where it came from."""
    return [dict(zip(around, image)) for image in itertools.permutations(around)
            if all(u != w for u, w in zip(around, image))]


def _loops(transition: dict[Node, dict[Node, Node]]) -> list[list[tuple[Node, Node]]]:
    """The closed walks the transitions make, each a list of directed streets (from, to)."""
    unvisited = {(u, v) for v, table in transition.items() for u in table}
    loops = []
    while unvisited:
        edge = min(unvisited)
        loop = []
        while edge in unvisited:
            unvisited.remove(edge)
            loop.append(edge)
            edge = (edge[1], transition[edge[1]][edge[0]])
        loops.append(loop)
    return loops


def circuit_path(circuit: list[Node], pitch_m: float, turn_radius_m: float) -> tuple[list, tuple[float, float], float]:
    """One lap of the circuit as drive segments (straights and 90 deg arcs of turn_radius_m at the crossings),
    from the middle of its first street back to it: (segments, start xy [m], start yaw [deg])."""
    if not 0 < turn_radius_m < pitch_m / 2:
        raise ConfigError(f"the turn radius must be within (0, {pitch_m / 2:g}) m, half a street's length")
    heading = [_direction(a, b) for a, b in zip(circuit, circuit[1:] + circuit[:1])]
    segments, straight_m = [], pitch_m / 2
    for k in range(1, len(circuit) + 1):
        turn_deg = (heading[k % len(circuit)] - heading[k - 1] + 180) % 360 - 180
        if turn_deg == 0:
            straight_m += pitch_m
            continue
        segments += [Straight(length_m=straight_m - turn_radius_m), Arc(radius_m=turn_radius_m, angle_deg=turn_deg)]
        straight_m = pitch_m - turn_radius_m
    segments.append(Straight(length_m=straight_m - pitch_m / 2))
    (i0, j0), (i1, j1) = circuit[0], circuit[1]
    return segments, (pitch_m * (i0 + i1) / 2, pitch_m * (j0 + j1) / 2), float(heading[0])


def _direction(a: Node, b: Node) -> int:
    """Heading from crossing a to its neighbour b [deg, counter-clockwise from east]."""
    return {(1, 0): 0, (0, 1): 90, (-1, 0): 180, (0, -1): 270}[(b[0] - a[0], b[1] - a[1])]


def looped_drive(lap: list, start_xy: tuple[float, float], start_yaw_deg: float, duration_s: float,
                 rng: np.random.Generator, cruise_m_s: tuple[float, float] = (6.0, 12.0), turn_m_s: float = 4.0,
                 stop_probability: float = 0.15, stop_s: tuple[float, float] = (2.0, 6.0),
                 accel_m_s2: float = 1.5, brake_m_s2: float = 2.0) -> Drive:
    """The lap driven again and again for duration_s [s]: each straight at a cruise speed drawn in cruise_m_s,
    every arc at turn_m_s, the straight before an arc ending with a stop of stop_s [s] with stop_probability,
    speeds changing at accel_m_s2 and brake_m_s2 (piecewise-linear speed, exact on the path's lengths).
    A lap of anything but straights and arcs (a turn on the spot) is refused: its speed profile has no length
    to cover."""
    others = sorted({seg.kind for seg in lap if not isinstance(seg, Straight | Arc)})
    if others:
        raise ConfigError(f"looped_drive: a lap is straights and arcs, not {', '.join(others)}")
    segments, knots = [], [(0.0, turn_m_s)]
    while knots[-1][0] <= duration_s:
        for k, seg in enumerate(lap):
            v_in = knots[-1][1]
            if isinstance(seg, Arc):
                phases = _phases(seg.length_m, v_in, turn_m_s, turn_m_s, accel_m_s2, brake_m_s2)
            else:
                stop = isinstance(lap[(k + 1) % len(lap)], Arc) and rng.uniform() < stop_probability
                cruise = rng.uniform(*cruise_m_s)
                phases = _phases(seg.length_m, v_in, cruise, 0.0 if stop else turn_m_s, accel_m_s2, brake_m_s2)
                if stop:
                    phases.append((rng.uniform(*stop_s), 0.0))
            for dt_s, speed in phases:
                knots.append((knots[-1][0] + dt_s, speed))
        segments += lap
    return Drive(segments=segments, speed_knots=knots, start_xy=start_xy, start_yaw_deg=start_yaw_deg)


def _phases(length_m: float, v_in: float, v_cruise: float, v_out: float, accel: float,
            brake: float) -> list[tuple[float, float]]:
    """(duration s, speed at its end m/s) of the speed ramps that cover length_m from v_in to v_out by way
    of v_cruise (lowered to what the length allows), with the given acceleration and braking [m/s2]."""
    v_cruise = min(v_cruise, np.sqrt((length_m + v_in ** 2 / (2 * accel) + v_out ** 2 / (2 * brake))
                                     / (1 / (2 * accel) + 1 / (2 * brake))))
    if v_cruise < max(v_in, v_out) - 1e-9:
        raise ConfigError(f"a {length_m:.1f} m segment is too short to go from {v_in:g} to {v_out:g} m/s")
    ramp_up_m = (v_cruise ** 2 - v_in ** 2) / (2 * accel)
    ramp_down_m = (v_cruise ** 2 - v_out ** 2) / (2 * brake)
    cruise_m = length_m - ramp_up_m - ramp_down_m
    phases = [((v_cruise - v_in) / accel, v_cruise), (cruise_m / v_cruise, v_cruise),
              ((v_cruise - v_out) / brake, v_out)]
    return [(dt, v) for dt, v in phases if dt > 1e-9]
