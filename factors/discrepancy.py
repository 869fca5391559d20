"""Generic discrepancy models: a smooth error of one channel of a return as a function of one regressor,
for physics no named effect describes. Pure NumPy and SciPy, no I/O.

A discrepancy moves one channel (factors.channels) of every return by f(x), x the return's regressor:

    range      measured minus true range [m]             channel d_rho   = -f(x)
    azimuth    true minus modelled beam azimuth [rad]    channel d_theta = +f(x)
    elevation  true minus modelled beam elevation [rad]  channel d_phi   = +f(x)
    time       stamped minus true time [s]               channel d_t     = -f(x)

(the signs of diagnosis.json's `curve.y`, RECORDING.md "Discovered effects"). f is

- a cubic B-spline on knots at the regressor's quantiles (x clamped to [first, last knot]) for a continuous
  regressor, so that every basis function has returns under it;
- a Fourier series sin(k x), cos(k x), k = 1..K for the encoder azimuth (periodic);
- one value per fibre for the fibre;

with the constant removed (each basis function less its mean over [lo, hi], the last one dropped; per
fibre, less the mean over the fibres): a constant error of a channel is an ordinary parameter's (range
and angle offsets, the time offset), and the shape is what counts. The parameters are the functions'
coefficients in the channel's SI unit (m, rad, s).

A discrepancy is named by its spec, `channel~regressor/size/k0:k1:...` (its knots; the range [lo, hi] for the
azimuth and the fibre), so that a name alone rebuilds it (`Discrepancy.parse`), and it offers the candidate interface of factors.effects (name, unit, physics,
signature, parameters, dim, basis, magnitude_of).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from factors.channels import Basis, Context

CHANNELS = ("range", "azimuth", "elevation", "time")
# regressor -> its unit in curve.x
REGRESSORS = {"range": "m", "intensity": "intensity", "azimuth": "deg", "fibre": "id", "time": "s",
              "incidence": "deg", "speed": "m/s", "yaw_rate": "deg/s"}
CHANNEL_UNIT = {"range": "m", "azimuth": "deg", "elevation": "deg", "time": "s"}
CHANNEL_SIGN = {"range": -1.0, "azimuth": 1.0, "elevation": 1.0, "time": -1.0}
CHANNEL_ERROR = {"range": "measured minus true range", "azimuth": "true minus modelled beam azimuth",
                 "elevation": "true minus modelled beam elevation", "time": "stamped minus true time"}
DEGREE = 3
MIN_DISTINCT = 20  # a regressor with fewer distinct values is a category or a constant, not a smooth variable
GRID = 200  # points over [lo, hi] for the centring constants, the magnitude and the curve
PREFIX_SEPARATOR = "~"


def regressor_values(context: Context, regressor: str) -> np.ndarray | None:
    """The regressor of each return in curve.x's unit (REGRESSORS), or None when the data lack it."""
    values = {
        "range": lambda: context.range_m,
        "intensity": lambda: context.intensity,
        "azimuth": lambda: np.degrees(np.mod(context.azimuth_rad, 2 * np.pi)),
        "fibre": lambda: context.fibre.astype(np.float64),
        "time": lambda: context.elapsed_s,
        "incidence": lambda: np.degrees(np.arccos(np.clip(context.cos_incidence, 0.0, 1.0))),
        "speed": lambda: context.speed_m_s,
        "yaw_rate": lambda: None if context.yaw_rate_rad_s is None else np.degrees(context.yaw_rate_rad_s),
    }
    out = values[regressor]()
    return None if out is None else np.asarray(out, dtype=np.float64)


def is_discrepancy(name: str) -> bool:
    return PREFIX_SEPARATOR in name


@dataclass(frozen=True)
class Discrepancy:
    """f(x) on one channel (module docstring): size parameters; knots (curve.x's unit): the B-spline's
    (increasing, the first and last bound x), or (lo, hi) for the azimuth and the fibre."""

    channel: str
    regressor: str
    size: int
    knots: tuple[float, ...]

    def __post_init__(self):
        if self.channel not in CHANNELS:
            raise ValueError(f"discrepancy channel {self.channel!r}: one of {', '.join(CHANNELS)}")
        if len(self.knots) < 2 or np.any(np.diff(self.knots) <= 0):
            raise ValueError(f"discrepancy {self.channel}~{self.regressor}: knots {self.knots} do not increase")
        if self.regressor not in ("azimuth", "fibre") and self.size != len(self.knots) + DEGREE - 2:
            raise ValueError(f"discrepancy {self.channel}~{self.regressor}: {len(self.knots)} knots give "
                             f"{len(self.knots) + DEGREE - 2} parameters, not {self.size}")

    @property
    def lo(self) -> float:
        return self.knots[0]

    @property
    def hi(self) -> float:
        return self.knots[-1]

    @classmethod
    def parse(cls, name: str) -> Discrepancy:
        """The discrepancy a name (`channel~regressor/size/k0:k1:...`) describes."""
        head, size, knots = name.split("/")
        channel, regressor = head.split(PREFIX_SEPARATOR)
        return cls(channel, regressor, int(size), tuple(float(k) for k in knots.split(":")))

    @classmethod
    def over(cls, channel: str, regressor: str, x: np.ndarray, n_fibres: int, size: int = 6) -> Discrepancy | None:
        """A discrepancy of about size parameters over the regressor's values x: knots at x's quantiles from the
        1st to the 99th percentile (every fibre for the fibre, the whole turn for the azimuth); None when x has
        fewer than MIN_DISTINCT distinct values or too few distinct quantiles for a curve."""
        if regressor == "fibre":
            return cls(channel, regressor, n_fibres - 1, (0.0, float(n_fibres - 1)))
        if regressor == "azimuth":
            return cls(channel, regressor, size, (0.0, 360.0))
        if len(np.unique(np.round(x, 9))) < MIN_DISTINCT:
            return None
        quantiles = np.unique([float(f"{q:.6g}") for q in np.percentile(x, np.linspace(1, 99, size - DEGREE + 2))])
        if len(quantiles) < size - DEGREE + 2:
            return None
        return cls(channel, regressor, size, tuple(quantiles))

    @classmethod
    def uniform(cls, channel: str, regressor: str, size: int, lo: float, hi: float) -> Discrepancy:
        """size parameters over [lo, hi]: uniform knots for a B-spline (the range for the azimuth and the fibre)."""
        if regressor in ("azimuth", "fibre"):
            return cls(channel, regressor, size, (lo, hi))
        return cls(channel, regressor, size, tuple(np.linspace(lo, hi, size - DEGREE + 2)))

    @property
    def name(self) -> str:
        knots = ":".join(f"{k:.6g}" for k in self.knots)
        return f"{self.channel}{PREFIX_SEPARATOR}{self.regressor}/{self.size}/{knots}"

    @property
    def unit(self) -> str:
        return CHANNEL_UNIT[self.channel]

    @property
    def physics(self) -> str:
        return f"a {self.channel} error that varies with the {self.regressor}"

    @property
    def signature(self) -> str:
        return f"{CHANNEL_ERROR[self.channel]} as a smooth function of the {self.regressor}, its constant removed"

    @property
    def parameters(self) -> str:
        kind = {"azimuth": "Fourier coefficients", "fibre": "per-fibre values"}.get(self.regressor, "B-spline coefficients")
        return f"{kind} of the {CHANNEL_ERROR[self.channel]} [m, rad or s]"

    def dim(self, n_fibres: int) -> int:
        return self.size

    def design(self, x: np.ndarray) -> np.ndarray:
        """(N, size) basis functions at x (curve.x's unit), constant removed."""
        x = np.asarray(x, dtype=np.float64)
        if self.regressor == "azimuth":
            angle = np.radians(x)[:, None] * np.arange(1, self.size // 2 + 1)
            return np.column_stack([np.sin(angle), np.cos(angle)])[:, :self.size]
        if self.regressor == "fibre":
            n = self.size + 1
            one_hot = (np.rint(x).astype(np.int64)[:, None] == np.arange(n)).astype(np.float64)
            return (one_hot - 1.0 / n)[:, :self.size]
        knots = np.r_[[self.lo] * DEGREE, self.knots, [self.hi] * DEGREE]
        grid = np.linspace(self.lo, self.hi, GRID)
        centre = BSpline.design_matrix(grid, knots, DEGREE).toarray().mean(axis=0)
        B = BSpline.design_matrix(np.clip(x, self.lo, self.hi), knots, DEGREE).toarray() - centre
        return B[:, :self.size]

    def basis(self, context: Context) -> Basis:
        x = regressor_values(context, self.regressor)
        if x is None:
            raise ValueError(f"the returns have no {self.regressor} for discrepancy {self.name}")
        return Basis(self.size, **{self.channel: CHANNEL_SIGN[self.channel] * self.design(x)})

    def grid(self) -> np.ndarray:
        """x over [lo, hi] (every fibre for the fibre) at which the curve is drawn."""
        if self.regressor == "fibre":
            return np.arange(self.size + 1, dtype=np.float64)
        return np.linspace(self.lo, self.hi, GRID)

    def curve(self, theta: np.ndarray, covariance: np.ndarray | None = None) -> dict:
        """{x, y, sigma}: the channel's error f(x) over the grid in `unit` (sigma: None without a covariance)."""
        x = self.grid()
        B = self.design(x) * (np.degrees(1.0) if self.unit == "deg" else 1.0)
        y = B @ np.asarray(theta, dtype=np.float64)
        sigma = None if covariance is None else np.sqrt(np.clip(np.einsum("ni,ij,nj->n", B, covariance, B), 0, None))
        return {"x": x, "y": y, "sigma": sigma}

    @property
    def boresight_part(self) -> np.ndarray | None:
        """Columns whose curve a rotation of the head also makes (the elevation's once-a-turn sinusoid is a
        tilted spin axis, which the boresight absorbs), or None."""
        if self.channel == "elevation" and self.regressor == "azimuth":
            return np.array([0, self.size // 2])
        return None

    def without_boresight(self, theta: np.ndarray, covariance: np.ndarray | None = None):
        """theta (and its covariance) with the boresight's part (boresight_part) set to zero."""
        part = self.boresight_part
        if part is None:
            return theta, covariance
        theta = np.array(theta, dtype=np.float64)
        theta[part] = 0.0
        if covariance is not None:
            covariance = np.array(covariance, dtype=np.float64)
            covariance[part, :] = 0.0
            covariance[:, part] = 0.0
        return theta, covariance

    def magnitude_of(self, theta: np.ndarray) -> float:
        """Peak-to-peak of f over the grid, in `unit`."""
        return float(np.ptp(self.curve(theta)["y"]))
