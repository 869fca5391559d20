"""Rerun views of a fit's residual field (rerun-sdk 0.41): the paired points p coloured by their
oriented residual and by each regressor of graphcal.diagnosis.locate, plus the binned means as time
series. Self-contained: one .rrd file per diagnosis, so the viewer work can wire it in later."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
from matplotlib import colormaps

from graphcal.diagnosis.locate import N_BINS, oriented_residual_m, regressors

RESIDUAL_RANGE_CM = 3.0


def colours(values: np.ndarray, low: float, high: float, cmap: str = "viridis") -> np.ndarray:
    """(N,) values -> (N,3) uint8 colours of a matplotlib colormap over [low, high]."""
    t = np.clip((values - low) / max(high - low, 1e-12), 0.0, 1.0)
    return (colormaps[cmap](t)[:, :3] * 255).astype(np.uint8)


def log_residual_field(fit, path: str | Path, application_id: str = "graphcal-diagnose") -> Path:
    """Write path (.rrd): residual/<regressor> point clouds (p's world points, local origin) coloured
    by the regressor, residual/oriented coloured by the residual (blue -3 cm .. red +3 cm), and
    binned/<regressor> the robust mean residual [cm] per bin, against the bin's centre."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stream = rr.RecordingStream(application_id)
    stream.save(path)
    points = fit.points_m[fit.pairs.index_p]
    residual_cm = oriented_residual_m(fit) * 100.0
    stream.log("residual/oriented", rr.Points3D(points, colors=colours(residual_cm, -RESIDUAL_RANGE_CM,
                                                                       RESIDUAL_RANGE_CM, "coolwarm"), radii=0.03))
    for name, values in regressors(fit).items():
        low, high = np.quantile(values, [0.01, 0.99])
        stream.log(f"residual/{name}", rr.Points3D(points, colors=colours(values, low, high), radii=0.03))
        edges = np.unique(np.quantile(values, np.linspace(0, 1, N_BINS + 1)))
        index = np.clip(np.digitize(values, edges) - 1, 0, len(edges) - 2)
        for b in range(len(edges) - 1):
            inside = index == b
            if inside.any():
                stream.set_time("bin", sequence=b)
                stream.log(f"binned/{name}", rr.Scalars(float(np.median(residual_cm[inside]))))
    stream.flush()
    stream.disconnect()
    return path
