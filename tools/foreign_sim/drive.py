"""Vehicle dynamics: a curvature-continuous path, a smooth speed programme, a car resting on its
four wheels on the ground, suspension pitch/roll from the accelerations, and the recorded INS.

Layout frame: x, y horizontal, z up [m]; heading counter-clockwise from x. Body frame: x forward,
y left, z up, origin on the ground under the rear axle. Attitudes: roll, pitch, yaw [deg] with
R = Rz(yaw) Ry(pitch) Rx(roll) (positive roll lowers the right side, positive pitch the nose).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

WHEELBASE_M = 2.70
TRACK_M = 1.58


# --- speed -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class SpeedProgramme:
    """Speed v(t) [m/s], t from the drive's start [s]: phases of (duration, target speed), each a
    raised-cosine ramp from the speed reached so far (a hold when the target is unchanged).
    Before t = 0 and after the last phase the speed is constant. Acceleration is continuous."""

    v0: float
    phases: tuple[tuple[float, float], ...]

    def _knots(self):
        durations = np.array([d for d, _ in self.phases], dtype=np.float64)
        speeds = np.array([self.v0] + [v for _, v in self.phases], dtype=np.float64)
        starts = np.concatenate([[0.0], np.cumsum(durations)])
        distance = np.concatenate([[0.0], np.cumsum(durations * (speeds[:-1] + speeds[1:]) / 2.0)])
        return durations, speeds, starts, distance

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distance s [m] from the start, speed [m/s], acceleration [m/s^2]) at times t [s]."""
        t = np.asarray(t, dtype=np.float64)
        durations, speeds, starts, distance = self._knots()
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(durations) - 1)
        tau = t - starts[k]
        d = durations[k]
        v_start, dv = speeds[k], speeds[k + 1] - speeds[k]
        before, after = t < 0.0, t >= starts[-1]
        u = np.clip(tau / d, 0.0, 1.0)
        v = v_start + dv * (1.0 - np.cos(np.pi * u)) / 2.0
        s = distance[k] + v_start * tau + dv / 2.0 * (tau - d / np.pi * np.sin(np.pi * u))
        a = dv * np.pi / (2.0 * d) * np.sin(np.pi * u)
        v = np.where(before, self.v0, np.where(after, speeds[-1], v))
        s = np.where(before, self.v0 * t, np.where(after, distance[-1] + speeds[-1] * (t - starts[-1]), s))
        a = np.where(before | after, 0.0, a)
        return s, v, a

    def extended(self, duration_s: float, rng) -> SpeedProgramme:
        """The programme continued with random cruise changes until it covers duration_s."""
        phases = list(self.phases)
        total = sum(d for d, _ in phases)
        speed = phases[-1][1] if phases else self.v0
        while total < duration_s + 1.0:
            hold = float(rng.uniform(3.0, 6.0))
            target = float(rng.uniform(5.0, 10.0))
            ramp = max(2.0, abs(target - speed) / 1.2)
            phases += [(hold, speed), (ramp, target)]
            total += hold + ramp
            speed = target
        return SpeedProgramme(self.v0, tuple(phases))


# --- path ------------------------------------------------------------------------------------
class Path:
    """A plane curve from its curvature kappa(s), piecewise linear in arc length s (straights,
    clothoids, arcs: curvature-continuous, so the yaw rate has no jumps). s = 0 at (0, 0)
    heading along +x; the curve extends straight before the first knot."""

    def __init__(self, knots_s, knots_kappa, s_min: float, s_max: float, ds: float = 0.01):
        ks, kk = np.asarray(knots_s, dtype=np.float64), np.asarray(knots_kappa, dtype=np.float64)
        keep = np.concatenate([[True], np.diff(ks) > 0])
        self.knots_s, self.knots_kappa = ks[keep], kk[keep]
        if s_min < self.knots_s[0] or s_max > self.knots_s[-1]:
            raise ValueError("the curvature knots must cover [s_min, s_max]")
        self.s = ds * np.arange(np.ceil(s_min / ds), np.floor(s_max / ds) + 1)  # holds s = 0 exactly
        self.heading = self.heading_at(self.s)
        c, sn = np.cos(self.heading), np.sin(self.heading)
        x = np.concatenate([[0.0], np.cumsum((c[1:] + c[:-1]) / 2.0 * ds)])
        y = np.concatenate([[0.0], np.cumsum((sn[1:] + sn[:-1]) / 2.0 * ds)])
        i0 = int(np.argmin(np.abs(self.s)))
        self.x, self.y = x - x[i0], y - y[i0]

    def heading_at(self, s) -> np.ndarray:
        """Exact integral of the piecewise-linear curvature, 0 at s = 0 [rad]."""
        ks, kk = self.knots_s, self.knots_kappa
        theta_k = np.concatenate([[0.0], np.cumsum(np.diff(ks) * (kk[1:] + kk[:-1]) / 2.0)])

        def theta(v):
            i = np.clip(np.searchsorted(ks, v, side="right") - 1, 0, len(ks) - 2)
            d = v - ks[i]
            slope = (kk[i + 1] - kk[i]) / (ks[i + 1] - ks[i])
            return theta_k[i] + kk[i] * d + 0.5 * slope * d * d

        return theta(np.asarray(s, dtype=np.float64)) - theta(np.array([0.0]))[0]

    def kappa(self, s) -> np.ndarray:
        return np.interp(s, self.knots_s, self.knots_kappa, left=self.knots_kappa[0], right=self.knots_kappa[-1])

    def at(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, heading) at arc lengths s."""
        return np.interp(s, self.s, self.x), np.interp(s, self.s, self.y), np.interp(s, self.s, self.heading)

    def offset(self, s0: float, s1: float, lateral: float, step: float = 0.25) -> np.ndarray:
        """(k, 2) polyline parallel to the path from s0 to s1, `lateral` metres to the left."""
        s = np.linspace(s0, s1, max(int((s1 - s0) / step), 1) + 1)
        x, y, h = self.at(s)
        return np.column_stack([x - lateral * np.sin(h), y + lateral * np.cos(h)])


def turn_knots(s0: float, angle_deg: float, radius_m: float, clothoid_m: float) -> tuple[list, float]:
    """Curvature knots of a turn (positive angle: left) with clothoid entry and exit; its end s."""
    angle = np.radians(abs(angle_deg))
    kappa = np.sign(angle_deg) / radius_m
    arc = angle * radius_m - clothoid_m
    if arc < 0:
        clothoid_m, arc = angle * radius_m, 0.0
    s1, s2, s3 = s0 + clothoid_m, s0 + clothoid_m + arc, s0 + 2 * clothoid_m + arc
    return [(s0, 0.0), (s1, kappa), (s2, kappa), (s3, 0.0)], s3


def path_from_plan(plan, s_min: float, s_max: float) -> tuple[Path, list[tuple[float, float]]]:
    """plan: list of ('straight', length) or ('turn', angle_deg, radius, clothoid) from s = 0.
    Returns the path (straight after the plan) and each turn's (start s, end s)."""
    knots = [(s_min - 1.0, 0.0), (0.0, 0.0)]
    s, turns = 0.0, []
    for item in plan:
        if item[0] == "straight":
            s += item[1]
        else:
            new, end = turn_knots(s, *item[1:])
            knots += new
            turns.append((s, end))
            s = end
    knots.append((max(s, s_max) + 1.0, 0.0))
    ks, kk = zip(*knots)
    return Path(ks, kk, s_min, max(s_max, s + 1.0)), turns


# --- vehicle ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Suspension:
    """Body attitude and height responses: second-order, natural frequency [Hz] and damping."""

    pitch_per_accel_deg: float   # nose-down pitch per m/s^2 of braking
    roll_per_accel_deg: float    # outward roll per m/s^2 of lateral acceleration
    pitch_hz: float = 1.4
    roll_hz: float = 1.2
    heave_hz: float = 1.6
    damping: float = 0.45
    roughness_deg: float = 0.02  # RMS pitch/roll from road roughness
    roughness_m: float = 0.002   # RMS heave from road roughness


def _second_order(u: np.ndarray, hz: float, damping: float, rate_hz: float) -> np.ndarray:
    w = 2 * np.pi * hz
    b, a = signal.bilinear([w * w], [1.0, 2 * damping * w, w * w], fs=rate_hz)
    zi = signal.lfilter_zi(b, a) * u[0]
    return signal.lfilter(b, a, u, zi=zi)[0]


def _roughness(n: int, hz: float, damping: float, rate_hz: float, rms: float, rng) -> np.ndarray:
    if rms <= 0:
        return np.zeros(n)
    w = _second_order(rng.standard_normal(n), hz, damping, rate_hz)
    w = _second_order(w, hz * 2.5, 0.7, rate_hz)  # roll off the high frequencies once more
    return rms * w / max(np.std(w), 1e-12)


@dataclass(frozen=True)
class VehicleTruth:
    time: np.ndarray       # (n,) s, drive clock (0 = start of the returns)
    position: np.ndarray   # (n, 3) m, layout frame, body origin
    rpy_deg: np.ndarray    # (n, 3) roll, pitch, yaw (yaw unwrapped, layout frame)
    speed: np.ndarray
    accel_long: np.ndarray
    accel_lat: np.ndarray
    yaw_rate_deg: np.ndarray


def drive_vehicle(path: Path, speed: SpeedProgramme, ground_z, t: np.ndarray, suspension: Suspension,
                  rng, rate_hz: float) -> VehicleTruth:
    """The car on the ground along `path` at the times t (uniform at rate_hz, drive clock)."""
    settle = int(3.0 * rate_hz)  # let the suspension filters settle before the first sample
    t_all = np.concatenate([t[0] - np.arange(settle, 0, -1) / rate_hz, t])
    s, v, a_long = speed.evaluate(t_all)
    x, y, heading = path.at(s)
    kappa = path.kappa(s)
    a_lat = v * v * kappa
    yaw_rate = v * kappa
    fwd = np.column_stack([np.cos(heading), np.sin(heading)])
    left = np.column_stack([-np.sin(heading), np.cos(heading)])
    rear = np.column_stack([x, y])
    front = rear + WHEELBASE_M * fwd
    half = TRACK_M / 2.0
    wheels = np.vstack([rear + half * left, rear - half * left, front + half * left, front - half * left])
    z_rl, z_rr, z_fl, z_fr = np.split(ground_z(wheels), 4)
    pitch_road = -np.degrees(np.arctan2((z_fl + z_fr - z_rl - z_rr) / 2.0, WHEELBASE_M))
    roll_road = np.degrees(np.arctan2((z_rl + z_fl - z_rr - z_fr) / 2.0, TRACK_M))
    z = (z_rl + z_rr) / 2.0
    n = len(t_all)
    sp = suspension
    pitch = pitch_road + _second_order(-sp.pitch_per_accel_deg * a_long, sp.pitch_hz, sp.damping, rate_hz) \
        + _roughness(n, sp.pitch_hz, sp.damping, rate_hz, sp.roughness_deg, rng)
    roll = roll_road + _second_order(sp.roll_per_accel_deg * a_lat, sp.roll_hz, sp.damping, rate_hz) \
        + _roughness(n, sp.roll_hz, sp.damping, rate_hz, sp.roughness_deg, rng)
    z = z + _roughness(n, sp.heave_hz, sp.damping, rate_hz, sp.roughness_m, rng)
    keep = slice(settle, None)
    return VehicleTruth(time=t, position=np.column_stack([x, y, z])[keep],
                        rpy_deg=np.column_stack([roll, pitch, np.degrees(heading)])[keep],
                        speed=v[keep], accel_long=a_long[keep], accel_lat=a_lat[keep],
                        yaw_rate_deg=np.degrees(yaw_rate)[keep])


# --- recorded INS ----------------------------------------------------------------------------
def _slow_wander(t: np.ndarray, amplitude: float, rng, periods=(40.0, 200.0)) -> np.ndarray:
    """A smooth drift starting at 0 and staying within +-amplitude."""
    if amplitude <= 0:
        return np.zeros_like(t)
    p = rng.uniform(*periods, 2)
    phase = rng.uniform(0, 2 * np.pi, 2)
    w = rng.uniform(0.3, 1.0, 2)
    w /= w.sum()
    tau = t - t[0]
    wave = sum(w[i] * (np.sin(2 * np.pi * tau / p[i] + phase[i]) - np.sin(phase[i])) for i in range(2))
    return amplitude * wave / 2.0


def recorded_ins(time: np.ndarray, position: np.ndarray, rpy_deg: np.ndarray, rng, noise_m: float,
                 noise_deg: float, drift_m: float = 0.0, drift_deg: float = 0.0):
    """Truth samples -> INS output: white noise per sample plus an optional slow drift."""
    pos = position + noise_m * rng.standard_normal(position.shape)
    rpy = rpy_deg + noise_deg * rng.standard_normal(rpy_deg.shape)
    if drift_m > 0:
        pos = pos + np.column_stack([_slow_wander(time, drift_m, rng) for _ in range(2)]
                                    + [_slow_wander(time, drift_m / 2.0, rng)])
    if drift_deg > 0:
        rpy = rpy + np.column_stack([_slow_wander(time, drift_deg / 3.0, rng), _slow_wander(time, drift_deg / 3.0, rng),
                                     _slow_wander(time, drift_deg, rng)])
    return pos, rpy
