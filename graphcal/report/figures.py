"""The report's figures as PNG bytes (matplotlib, Agg): each function takes arrays and returns a PNG."""

from __future__ import annotations

import io

import numpy as np

WIDTH_IN, DPI = 11.0, 100
BEFORE, AFTER, TRUTH, SIGMA = "#d0503c", "#2a9d50", "#f0a020", "#1e6edc"


def _figure(rows: int = 1, columns: int = 1, height_in: float = 3.8):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 10, "axes.titlesize": 11, "axes.grid": True, "grid.alpha": 0.3})
    figure, axes = plt.subplots(rows, columns, figsize=(WIDTH_IN, height_in), squeeze=False)
    return figure, axes.ravel()


def _png(figure, tight: bool = True) -> bytes:
    import matplotlib.pyplot as plt

    if tight:  # a figure with its own layout (cloud_png) keeps it
        figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI)
    plt.close(figure)
    return buffer.getvalue()


def energy_png(history: list[dict]) -> bytes:
    """J [cm^2] before and after each outer iteration's solve (log scale) and the weight sum, with
    the stage and phase of each iteration marked."""
    figure, (left, right) = _figure(1, 2)
    iteration = np.arange(len(history))
    before = np.array([float(row["energy_cm2"]) for row in history])
    after = np.array([float(row["energy_after_cm2"]) for row in history])
    left.semilogy(iteration, before, "o-", color=BEFORE, label="J before the solve")
    left.semilogy(iteration, after, "s--", color=AFTER, label="J after the solve")
    left.set(xlabel="outer iteration", ylabel="J [cm²] (log scale)", title="Energy J per outer iteration")
    right.plot(iteration, [float(row["weight_sum"]) for row in history], "o-", color=SIGMA)
    right.set(xlabel="outer iteration", ylabel="weight sum Σw", title="Weight sum of the pairs per outer iteration")
    for axes in (left, right):
        _mark_phases(axes, history)
        axes.xaxis.get_major_locator().set_params(integer=True)
    left.legend(loc="upper right")
    return _png(figure)


def _mark_phases(axes, history: list[dict]) -> None:
    """Vertical lines where the stage or phase changes, labelled at the top."""
    previous = None
    for k, row in enumerate(history):
        label = f"{row['mode']} {row['phase']}"
        if label != previous:
            axes.axvline(k - 0.5, color="0.6", lw=0.8, ls=":")
            axes.annotate(label, (k - 0.4, 1.0), xycoords=("data", "axes fraction"), va="top", fontsize=8,
                          color="0.35", rotation=90)
            previous = label


def residuals_png(before_m: np.ndarray, after_m: np.ndarray) -> bytes:
    """Histograms of the signed residuals [cm] before and after (log counts): on the before's
    range (left) and zoomed on the after's own range (right)."""
    figure, (left, right) = _figure(1, 2)
    before, after = np.asarray(before_m) * 100.0, np.asarray(after_m) * 100.0
    rms = {name: float(np.sqrt(np.mean(v ** 2))) for name, v in (("before", before), ("after", after))}
    panels = ((left, (("before", before, BEFORE), ("after", after, AFTER)), before, "before and after"),
              (right, (("after", after, AFTER),), after, "after, zoomed"))
    for axes, series, ranged, title in panels:
        limit = max(float(np.percentile(np.abs(ranged), 99)), 1e-3)
        edges = np.linspace(-limit, limit, 81)
        for name, values, color in series:
            axes.hist(np.clip(values, edges[0], edges[-1]), edges, histtype="stepfilled", alpha=0.45, color=color,
                      label=f"{name}: RMS {rms[name]:.3g} cm")
        axes.set(xlabel="signed residual n·(p−m) [cm]", ylabel="pairs (log scale)", yscale="log",
                 title=f"{title} (beyond the range: in the end bins)")
        axes.legend(loc="upper right")
    return _png(figure)


def cloud_png(before_m: np.ndarray, before_residual_m: np.ndarray, after_m: np.ndarray,
              after_residual_m: np.ndarray) -> bytes:
    """The paired returns p (K,3) [m, world] of the cloud before and after, coloured by |residual|
    [cm] on one scale (the before's 99th percentile), about the before's median point: seen from
    above (top row) and from the south, east against up (bottom row)."""
    import matplotlib.pyplot as plt

    _figure()  # the style; this figure needs a layout that leaves room for one shared colour bar
    plt.close()
    figure, axes = plt.subplots(2, 2, figsize=(WIDTH_IN, 8.5), layout="constrained", height_ratios=(2.2, 1))
    centre = np.median(before_m, axis=0)
    limit = max(float(np.percentile(np.abs(before_residual_m), 99)) * 100.0, 1e-3)
    for column, (name, points, residual) in enumerate((("before", before_m, before_residual_m),
                                                       ("after", after_m, after_residual_m))):
        local = np.asarray(points) - centre
        colour = np.abs(np.asarray(residual)) * 100.0
        order = np.argsort(colour)  # the largest residuals drawn last, on top
        style = {"c": colour[order], "s": 1, "cmap": "viridis", "vmin": 0, "vmax": limit, "rasterized": True}
        shown = axes[0, column].scatter(local[order, 0], local[order, 1], **style)
        axes[0, column].set(xlabel="east [m]", ylabel="north [m]", title=f"{name}: from above", aspect="equal")
        axes[1, column].scatter(local[order, 0], local[order, 2], **style)
        axes[1, column].set(xlabel="east [m]", ylabel="up [m]", title=f"{name}: from the south")
    figure.colorbar(shown, ax=axes, label="|residual| [cm]", shrink=0.6)
    return _png(figure, tight=False)


def intrinsics_png(values: np.ndarray, sigma: np.ndarray, truth: np.ndarray | None, unobservable: np.ndarray,
                   names: list[str], reference_fibre: int) -> bytes:
    """Per-fibre offsets (n, 4) in display units with 1-sigma error bars, truth when known;
    unobservable ones (held at nominal) marked as grey crosses at 0."""
    figure, axes = _figure(2, 2, height_in=6.5)
    fibre = np.arange(len(values))
    for k, (ax, name) in enumerate(zip(axes, names)):
        shown = ~unobservable[:, k]
        ax.errorbar(fibre[shown], values[shown, k], yerr=np.nan_to_num(sigma[shown, k]), fmt="o", ms=3.5,
                    color=SIGMA, ecolor=SIGMA, capsize=2, label="estimate ± 1σ")
        if truth is not None:
            ax.plot(fibre, truth[:, k], "_", ms=9, mew=2, color=TRUTH, label="truth")
        if unobservable[:, k].any():
            ax.plot(fibre[~shown], np.zeros((~shown).sum()), "x", color="0.5", label="unobservable (held at 0)")
        ax.axvline(reference_fibre, color="0.7", lw=0.8, ls=":")
        ax.set(xlabel="fibre (dotted: the reference)", ylabel=name, title=name)
    axes[0].legend(loc="best", fontsize=8)
    return _png(figure)


def corrections_png(time_s: np.ndarray, values_cm: np.ndarray, sigma_cm: np.ndarray,
                    truth_cm: np.ndarray | None) -> bytes:
    """Translation corrections (C, 3) [cm] per control time with 1-sigma, and the INS error at
    those times when known (NaN outside the trajectory), shifted by the mean of (estimate - truth):
    a common translation of the whole drive is unobservable, only the shape can match."""
    figure, axes = _figure(1, 3, height_in=3.6)
    shift = np.nanmean(values_cm - truth_cm, axis=0) if truth_cm is not None else None
    for k, (ax, axis) in enumerate(zip(axes, "xyz")):
        ax.errorbar(time_s, values_cm[:, k], yerr=np.nan_to_num(sigma_cm[:, k]), fmt="o-", ms=3.5, color=SIGMA,
                    capsize=2, label="estimate ± 1σ")
        if truth_cm is not None:
            ax.plot(time_s, truth_cm[:, k] + shift[k], "s--", ms=8, mfc="none", mew=1.5, color=TRUTH, zorder=3,
                    label="true INS error + common shift")
        ax.set(xlabel="control time [s]", ylabel=f"d{axis} [cm]", title=f"correction along {axis} (world)")
    axes[0].legend(loc="best", fontsize=8)
    return _png(figure)


def timings_png(timings_s: dict[str, float]) -> bytes:
    """Seconds per stage, as horizontal bars in run order."""
    names = list(timings_s)
    figure, (ax,) = _figure(height_in=0.6 + 0.32 * len(names))
    bars = ax.barh(np.arange(len(names)), [timings_s[n] for n in names], color=SIGMA)
    ax.bar_label(bars, fmt="%.2f s", padding=3, fontsize=8)
    ax.margins(x=0.12)
    ax.set_yticks(np.arange(len(names)), names)
    ax.invert_yaxis()
    ax.set(xlabel="seconds", title="Time per stage")
    return _png(figure)


def _span(y: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    """The y range of a curve's band with a tenth of margin each side."""
    low, high = float(np.min(y - sigma)), float(np.max(y + sigma))
    margin = 0.1 * max(high - low, 1e-12)
    return low - margin, high + margin


def discovered_png(channel: str, regressor: str, unit: str, curve: dict, binned: dict) -> bytes:
    """A discovered effect: its curve with the 1-sigma band in its unit against the regressor (left), and the
    fit's residuals binned against the same regressor before and after the effect was added [cm] (right)."""
    figure, (left, right) = _figure(1, 2, height_in=3.6)
    x, y = np.asarray(curve["x"], dtype=float), np.asarray(curve["y"], dtype=float)
    sigma = np.asarray(curve["sigma"] if curve.get("sigma") is not None else np.zeros_like(y), dtype=float)
    seen = np.asarray(curve.get("seen", np.ones_like(y, dtype=bool)), dtype=bool)
    shown = np.where(seen, y, np.nan)  # the points the data barely see: marked, not drawn as part of the curve
    left.fill_between(x, shown - sigma, shown + sigma, color=SIGMA, alpha=0.25, label="1σ band")
    left.plot(x, shown, color=SIGMA, label="estimate")
    if not seen.all():  # on the scale of the points the data see
        span = _span(y[seen], sigma[seen])
        left.plot(x[~seen], np.clip(y[~seen], *span), "o", mfc="none", color="#888",
                  label="barely seen (band over 5x the median; clipped to the axes)")
        left.set_ylim(*span)
    left.set(xlabel=regressor, ylabel=f"{channel} error [{unit}]", title=f"{channel} against {regressor}")
    left.legend(loc="best", fontsize=8)
    for label, colour in (("before", BEFORE), ("after", AFTER)):
        rows = binned[label]
        effect = np.array([np.nan if v is None else v for v in rows["effect_cm"]], dtype=float)
        right.plot(rows["x"], effect, "o-", ms=4, color=colour, label=f"{label} it was added")
    right.axhline(0.0, color="#888", lw=0.8)
    right.set(xlabel=f"{regressor} (bin centre)", ylabel="binned residual [cm]",
              title="residuals less the field's trimmed mean, per quantile bin")
    right.legend(loc="best", fontsize=8)
    return _png(figure)
