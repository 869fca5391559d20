"""Locate structure in the residual field of a fit: binned robust means against each regressor
(fibre, azimuth, time within the revolution, drive time and distance, range, incidence, speed, yaw
rate, intensity) with effect sizes in cm, tests on cluster means (pairs are correlated within a
block of space and time) with Benjamini-Hochberg control over every bin, and Ljung-Box whiteness
along time and azimuth.

The residual of a pair is d = n . (p - m) with the normal turned away from p's sensor (along the
beam), so that a positive d puts p behind the surface m lies on, seen from the sensor: range-like
errors keep their sign across surfaces. A bin's effect is its trimmed mean less the whole field's:
structure against the regressor, not a common offset.
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from statsmodels.stats.diagnostic import acorr_ljungbox

N_BINS = 8
MIN_CLUSTERS = 5
Q_LEVEL = 1e-3
MIN_EFFECT_CM = 0.1  # smaller bin means are reported as nothing, however significant (10^5 pairs)


def regressors(fit) -> dict[str, np.ndarray]:
    """Per pair (the values at p): name -> (K,) regressor; the range is the stand-in's (ReturnContext.range_m)."""
    data, p = fit.data, fit.pairs.index_p
    context = fit.model.context
    speed = np.linalg.norm(context.velocity[p], axis=1)
    distance = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(data.X_nav, axis=0), axis=1))]
    intensity = fit.recording.points.take(["intensity"], data.rows)["intensity"].astype(np.float64)
    return {"fibre": data.fibre[p].astype(np.float64),
            "azimuth_deg": np.degrees(data.azimuth_rad[p]),
            "sweep_fraction": context.sweep_s[p] * data.sensor.rotation_hz,
            "time_s": context.elapsed_s[p],
            "distance_m": distance[p],
            "range_m": context.range_m[p],
            "incidence_deg": np.degrees(np.arccos(context.cos_incidence[p])),
            "speed_m_s": speed,
            "yaw_rate_deg_s": np.degrees(context.omega[p, 2]),
            "intensity": intensity[p]}


def oriented_residual_m(fit) -> np.ndarray:
    """d = n . (p - m) [m] with n turned away from p's sensor (K,): positive when p lies behind m's
    surface."""
    p, m = fit.pairs.index_p, fit.pairs.index_m
    n = fit.pairs.normal
    away = np.sign(np.einsum("ni,ni->n", n, fit.points_m[p] - fit.data.X_nav[p]))
    return away * np.einsum("ni,ni->n", n, fit.points_m[p] - fit.points_m[m])


def centred_residual_cm(fit) -> np.ndarray:
    """The oriented residuals [cm] less their trimmed mean: structure, not a common offset (K,)."""
    residual = oriented_residual_m(fit) * 100.0
    return residual - stats.trim_mean(residual, 0.1)


def bins(values: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A regressor's bin edges (one bin per fibre, else N_BINS quantile bins) and each value's bin."""
    if name == "fibre":
        edges = np.arange(values.min(), values.max() + 2) - 0.5
    else:
        edges = np.unique(np.quantile(values, np.linspace(0, 1, N_BINS + 1)))
        edges[-1] = np.nextafter(edges[-1], np.inf)
    return edges, np.digitize(values, edges) - 1


def binned_against(fit, values: np.ndarray) -> dict:
    """The centred oriented residuals [cm] of a fit's pairs binned against a regressor's values at p (K,): bin
    centres (x, the regressor's unit), trimmed means (effect_cm) and pair counts, N_BINS quantile bins."""
    edges, index = bins(values, "")
    residual = centred_residual_cm(fit)
    inside = [index == b for b in range(len(edges) - 1)]
    return {"x": [float((edges[b] + edges[b + 1]) / 2) for b in range(len(edges) - 1)],
            "effect_cm": [float(stats.trim_mean(residual[i], 0.1)) if np.any(i) else None for i in inside],
            "n_pairs": [int(i.sum()) for i in inside]}


def locate(fit, top: int = 10) -> list[dict]:
    """The significant bins (q < Q_LEVEL after BH, |effect| >= MIN_EFFECT_CM), largest |effect| first, then the whiteness
    tests; each a dict of diagnosis.json's `locations`."""
    residual = centred_residual_cm(fit)
    cluster, _ = fit.clusters()
    rows = []
    for name, values in regressors(fit).items():
        edges, index = bins(values, name)
        for b in range(len(edges) - 1):
            inside = index == b
            clusters = np.unique(cluster[inside], return_inverse=True)[1]
            if clusters.size == 0 or clusters.max() + 1 < MIN_CLUSTERS:
                continue
            means = np.bincount(clusters, residual[inside]) / np.bincount(clusters)
            p_value = stats.ttest_1samp(means, 0.0).pvalue
            rows.append({"regressor": name, "bin": [float(edges[b]), float(edges[b + 1])],
                         "effect_cm": float(stats.trim_mean(residual[inside], 0.1)), "n_pairs": int(inside.sum()),
                         "n_clusters": int(clusters.max() + 1), "p_value": float(p_value)})
    if rows:
        q = stats.false_discovery_control([r["p_value"] for r in rows])
        for r, q_value in zip(rows, q):
            r["q_value"] = float(q_value)
    found = sorted((r for r in rows if r["q_value"] < Q_LEVEL and abs(r["effect_cm"]) >= MIN_EFFECT_CM), key=lambda r: -abs(r["effect_cm"]))[:top]
    return found + whiteness(fit, residual)


def whiteness(fit, residual_cm: np.ndarray, lags: int = 10) -> list[dict]:
    """Ljung-Box of the residuals of one fibre's pairs ordered by time, and by azimuth (the fibre with
    the most pairs); Q and its p-value."""
    fibre = fit.data.fibre[fit.pairs.index_p]
    busiest = np.bincount(fibre).argmax()
    of = np.flatnonzero(fibre == busiest)
    out = []
    for name, key in (("time_s", fit.data.time_s), ("azimuth_deg", fit.data.azimuth_rad)):
        order = of[np.argsort(key[fit.pairs.index_p[of]])]
        if len(order) <= 2 * lags:
            continue
        test = acorr_ljungbox(residual_cm[order], lags=[lags])
        out.append({"regressor": f"whiteness_{name}", "fibre": int(busiest), "lags": lags,
                    "statistic": float(test["lb_stat"].iloc[0]), "p_value": float(test["lb_pvalue"].iloc[0])})
    return out
