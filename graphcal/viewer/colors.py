"""Colours of the viewer: one per fibre (neighbours in elevation contrast), and value -> colour maps."""

from __future__ import annotations

import numpy as np
import rerun as rr

# matplotlib's tab20 and tab20b: 40 distinct colours, taken in elevation order so that fibres
# next to each other in elevation (those paired by the calibration) never share a colour
_PALETTES = ("tab20", "tab20b")


def fibre_colors(elevation_deg: np.ndarray) -> np.ndarray:
    """(n_fibres, 3) uint8 RGB, fibres ranked by elevation through a 40-colour palette."""
    import matplotlib

    palette = np.concatenate([matplotlib.colormaps[name].colors for name in _PALETTES])
    rank = np.argsort(np.argsort(elevation_deg))
    return (np.asarray(palette)[rank % len(palette)] * 255).astype(np.uint8)


def fibre_annotations(elevation_deg: np.ndarray) -> rr.AnnotationContext:
    """Class id = fibre index, with its label (fibre and elevation) and colour: hovering a point
    in the viewer names its fibre."""
    colors = fibre_colors(elevation_deg)
    return rr.AnnotationContext([rr.AnnotationInfo(id=fibre, label=f"fibre {fibre} ({elevation:+.2f} deg)",
                                                   color=tuple(int(c) for c in colors[fibre]))
                                 for fibre, elevation in enumerate(elevation_deg)])


def value_colors(values: np.ndarray, low: float, high: float, cmap: str = "viridis") -> np.ndarray:
    """(N, 3) uint8 RGB of values through a matplotlib colour map, clipped to [low, high]."""
    import matplotlib

    span = high - low if high > low else 1.0
    scaled = np.clip((np.asarray(values, dtype=np.float64) - low) / span, 0.0, 1.0)
    return (matplotlib.colormaps[cmap](scaled)[:, :3] * 255).astype(np.uint8)
