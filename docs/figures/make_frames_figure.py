"""Draw docs/figures/frames.png: the sensor, body and world frames of docs/concepts.md.

Run from anywhere:  python docs/figures/make_frames_figure.py
Deterministic (Agg backend, no random input, no timestamp in the PNG metadata).
The drawing is schematic: lengths and angles are exaggerated so that they can be read.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Arc, Circle, FancyArrowPatch, Rectangle  # noqa: E402

OUT = Path(__file__).resolve().parent / "frames.png"

BODY = "#1f4e9c"     # body frame
LIDAR = "#c0392b"    # lidar (sensor) frame
BEAM = "#d35400"     # a laser beam
GREY = "#555555"
WORLD = "#1e7b34"    # grid / world frame


def arrow(ax, start, end, color, width=2.0, style="-|>", scale=18, ls="-", z=3):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle=style, mutation_scale=scale, color=color,
                                 lw=width, linestyle=ls, zorder=z, shrinkA=0, shrinkB=0))


def arc_arrow(ax, centre, radius, start_deg, end_deg, color, clockwise):
    """An arc from start_deg to end_deg (page angles) with an arrow head at end_deg."""
    lo, hi = sorted((start_deg, end_deg))
    ax.add_patch(Arc(centre, 2 * radius, 2 * radius, theta1=lo, theta2=hi, color=color, lw=1.8, zorder=3))
    end = np.radians(end_deg)
    tip = np.array(centre) + radius * np.array([np.cos(end), np.sin(end)])
    step = np.radians(6.0) * (1 if clockwise else -1)
    tail = np.array(centre) + radius * np.array([np.cos(end + step), np.sin(end + step)])
    arrow(ax, tail, tip, color, width=1.8, scale=14)


def top_view(ax):
    """(a) Top view: body axes, lidar axes turned by the boresight yaw 90 deg, lever arm, azimuth."""
    ax.set_title("(a) top view (z out of the page)", fontsize=13, loc="left")
    ax.add_patch(Rectangle((-1.2, -1.0), 6.0, 2.0, fc="#eef2f8", ec=GREY, lw=1.2, zorder=1))
    ax.text(-1.1, -0.92, "vehicle", color=GREY, fontsize=10, va="bottom")
    # body frame at the origin: x forward, y left, z up (out of the page)
    arrow(ax, (0, 0), (1.1, 0), BODY, width=2.4)
    arrow(ax, (0, 0), (0, 1.1), BODY, width=2.4)
    ax.add_patch(Circle((0, 0), 0.09, fc="white", ec=BODY, lw=1.6, zorder=4))
    ax.add_patch(Circle((0, 0), 0.03, fc=BODY, ec=BODY, zorder=5))
    ax.text(0.3, 0.1, r"$x_b$ forward", color=BODY, fontsize=12, ha="left", va="bottom")
    ax.text(0.1, 1.12, r"$y_b$ left", color=BODY, fontsize=12, ha="left", va="bottom")
    ax.text(-0.15, -0.15, r"$z_b$ up", color=BODY, fontsize=11, ha="right", va="top")
    # lidar at the lever arm T (schematic length)
    L = np.array([3.8, 0.0])
    y_dim = -2.25
    arrow(ax, (0, y_dim), (L[0], y_dim), GREY, width=1.2, style="<|-|>", scale=12)
    ax.plot([0, 0], [-0.2, y_dim - 0.1], color=GREY, lw=0.8, ls=":")
    ax.plot([L[0], L[0]], [-0.2, y_dim - 0.1], color=GREY, lw=0.8, ls=":")
    ax.text(L[0] / 2, y_dim - 0.12, "lever arm T (body frame)\ndefault (0.80, 0, 1.90) m",
            color=GREY, fontsize=10.5, ha="center", va="top")
    # lidar axes: R = Rz(90 deg) -> x_L = +y_b, y_L = -x_b
    arrow(ax, L, L + (0, 1.0), LIDAR, width=2.4)
    arrow(ax, L, L + (-1.0, 0), LIDAR, width=2.4)
    ax.add_patch(Circle(L, 0.09, fc="white", ec=LIDAR, lw=1.6, zorder=4))
    ax.add_patch(Circle(L, 0.03, fc=LIDAR, ec=LIDAR, zorder=5))
    ax.text(L[0] - 0.1, L[1] + 1.2, r"$x_L$  ($\theta = 0°$)", color=LIDAR, fontsize=12, ha="right",
            va="bottom", bbox=dict(fc="white", ec="none", pad=0.5))
    ax.text(L[0] - 1.0, L[1] + 0.1, r"$y_L$", color=LIDAR, fontsize=12, ha="left", va="bottom")
    ax.text(L[0] + 0.12, L[1] - 0.12, r"$z_L$ up", color=LIDAR, fontsize=11, ha="left", va="top")
    # encoder angle ticks on a circle around the lidar: clockwise seen from above
    R = 1.45
    ax.add_patch(Circle(L, R, fill=False, ec=LIDAR, lw=0.8, ls="--", zorder=2))
    for theta, offset in ((90, 0.55), (180, 0.3), (270, 0.5)):
        page = np.radians(90 - theta)
        p = L + (R + offset) * np.array([np.cos(page), np.sin(page)])
        ax.text(*p, rf"$\theta={theta}°$", color=LIDAR, fontsize=11, ha="center", va="center",
                bbox=dict(fc="white", ec="none", pad=0.5))
    # beam at theta = 60 deg, and the azimuth arc from x_L clockwise to it
    theta = 60.0
    page = np.radians(90 - theta)
    direction = np.array([np.cos(page), np.sin(page)])
    arrow(ax, L, L + 3.2 * direction, BEAM, width=2.2)
    ax.text(*(L + 3.25 * direction + (0.05, 0.05)), "beam", color=BEAM, fontsize=12, ha="left", va="bottom")
    arc_arrow(ax, L, 0.7, 90, 90 - theta, LIDAR, clockwise=True)
    ax.text(*(L + 0.82 * np.array([np.cos(np.radians(70)), np.sin(np.radians(70))])), r"$\theta$",
            color=LIDAR, fontsize=14, ha="left", va="bottom")
    ax.text(-1.2, 3.55, "boresight yaw 90°:  R = Rz(90°),  $x_L = y_b$,  $y_L = -x_b$\n"
            r"azimuth $\theta$ clockwise seen from above; $\theta = 90°$ looks forward",
            fontsize=11, va="top")
    ax.set_xlim(-1.4, 7.8)
    ax.set_ylim(-3.0, 3.6)


def side_view(ax):
    """(b) Side view in the vertical plane of one beam: elevation, Hz, HDL-64E vertical offset."""
    ax.set_title("(b) one fibre, in the vertical plane of its beam", fontsize=12, loc="left")
    # spin axis z_L and the horizontal plane of the sensor
    arrow(ax, (0, -0.6), (0, 2.6), LIDAR, width=2.2)
    ax.text(0.1, 2.6, r"$z_L$ (spin axis)", color=LIDAR, fontsize=11, va="top")
    arrow(ax, (0, 0), (5.6, 0), LIDAR, width=1.2, style="-|>", ls="--")
    ax.text(5.6, -0.12, "horizontal, azimuth a", color=LIDAR, fontsize=10, ha="right", va="top")
    ax.add_patch(Circle((0, 0), 0.07, fc=LIDAR, ec=LIDAR, zorder=5))
    ax.text(-0.12, -0.05, "sensor\norigin", color=LIDAR, fontsize=9, ha="right", va="top")
    # fibre origin raised by Hz, beam at elevation e = phi_i + d_phi
    hz = 0.55
    e = np.radians(22.0)
    u = np.array([np.cos(e), np.sin(e)])
    o = np.array([0.0, hz])
    arrow(ax, (-0.35, 0), (-0.35, hz), GREY, width=1.2, style="<|-|>", scale=10)
    ax.text(-0.45, hz / 2, r"$H_{z,i}$", color=GREY, fontsize=12, ha="right", va="center")
    ax.plot([0, 3.2], [hz, hz], color=GREY, lw=0.9, ls=":")
    p = o + 4.6 * u
    arrow(ax, o, p, BEAM, width=2.2)
    ax.add_patch(Circle(p, 0.07, fc=BEAM, ec=BEAM, zorder=5))
    ax.text(*(p + (0.1, 0.0)), "return", color=BEAM, fontsize=10, va="center")
    ax.text(*(o + 2.6 * u + (-0.1, 0.22)), r"$\rho + \delta\rho_i$", color=BEAM, fontsize=13,
            ha="right", rotation=np.degrees(e), rotation_mode="anchor")
    ax.add_patch(Arc(o, 2.4, 2.4, theta1=0, theta2=np.degrees(e), color=BEAM, lw=1.5))
    ax.text(*(o + 1.3 * np.array([np.cos(e / 2), np.sin(e / 2)])), r"$\varphi_i + \delta\varphi_i$",
            color=BEAM, fontsize=12, va="center")
    # HDL-64E vertical offset V_i: the beam line displaced by V_i perpendicular to it
    n = np.array([-np.sin(e), np.cos(e)])
    v = 0.55
    ov = o + v * n
    ax.plot(*np.column_stack([ov, ov + 4.0 * u]), color=GREY, lw=1.3, ls="--")
    arrow(ax, o + 3.2 * u, o + 3.2 * u + v * n, GREY, width=1.1, style="<|-|>", scale=10)
    ax.text(*(ov + 4.05 * u), r"HDL-64E: $V_i$ shifts the beam" "\n" r"$\perp$ to it (0 for HDL-32E)",
            color=GREY, fontsize=9.5, va="bottom")
    ax.text(0.0, -0.95, r"eq. 4.2:  $x = (\rho+\delta\rho)\cos(\theta+\delta\theta)\cos(\varphi+\delta\varphi)$"
            "\n" r"             $y = -(\rho+\delta\rho)\sin(\theta+\delta\theta)\cos(\varphi+\delta\varphi)$"
            "\n" r"             $z = (\rho+\delta\rho)\sin(\varphi+\delta\varphi) + H_z$",
            fontsize=10, va="top")
    ax.set_xlim(-1.5, 7.2)
    ax.set_ylim(-2.3, 3.2)


def world_view(ax):
    """(c) Grid (projected CRS) axes vs local ENU: meridian convergence gamma."""
    ax.set_title("(c) world: grid axes vs local East-North-Up", fontsize=13, loc="left")
    gamma = np.radians(14.0)  # exaggerated; a few degrees at most within a UTM zone
    c = np.array([0.0, 0.0])
    arrow(ax, c, (3.3, 0), WORLD, width=2.4)
    arrow(ax, c, (0, 2.9), WORLD, width=2.4)
    ax.text(3.3, -0.15, "grid x (grid east)", color=WORLD, fontsize=11.5, ha="right", va="top")
    ax.text(0.1, 2.95, "grid y (grid north)", color=WORLD, fontsize=11.5, va="bottom")
    east = np.array([np.cos(gamma), np.sin(gamma)])
    north = np.array([-np.sin(gamma), np.cos(gamma)])
    arrow(ax, c, 1.7 * east, GREY, width=1.6, ls="--")
    arrow(ax, c, 2.5 * north, GREY, width=1.6, ls="--")
    ax.text(*(1.75 * east + (0.0, -0.08)), "E", color=GREY, fontsize=12, va="top")
    ax.text(*(2.55 * north + (-0.05, 0.02)), "N (true)", color=GREY, fontsize=11.5, ha="right", va="bottom")
    ax.add_patch(Arc(c, 4.0, 4.0, theta1=90, theta2=90 + np.degrees(gamma), color=GREY, lw=1.6))
    ax.text(*(2.3 * np.array([np.cos(np.radians(97)), np.sin(np.radians(97))])), r"$\gamma$",
            color=GREY, fontsize=15, ha="center", va="center")
    # vehicle heading: yaw counter-clockwise from East (geodetic) or from grid x (projected)
    yaw = np.radians(36.0)
    heading = np.array([np.cos(gamma + yaw), np.sin(gamma + yaw)])
    arrow(ax, c, 2.8 * heading, BODY, width=2.4)
    ax.text(*(2.85 * heading + (0.05, 0.0)), r"$x_b$", color=BODY, fontsize=13, va="bottom")
    ax.add_patch(Arc(c, 2.4, 2.4, theta1=np.degrees(gamma), theta2=np.degrees(gamma + yaw), color=BODY, lw=1.6))
    mid = gamma + yaw * 0.5
    ax.text(*(1.3 * np.array([np.cos(mid), np.sin(mid)])), r"yaw$_{ENU}$", color=BODY, fontsize=12,
            ha="left", va="center")
    ax.add_patch(Arc(c, 5.4, 5.4, theta1=0, theta2=np.degrees(gamma + yaw), color=WORLD, lw=1.4, ls=":"))
    mid = np.radians(9.0)
    ax.text(*(2.8 * np.array([np.cos(mid), np.sin(mid)])), r"yaw$_{grid}$ = yaw$_{ENU} + \gamma$",
            color=WORLD, fontsize=12, va="center")
    ax.text(-0.3, -0.75, "gamma: pyproj meridian_convergence, counter-clockwise\n"
            "from grid north to true north (> 0 east of the central\n"
            "meridian, northern hemisphere); drawn 14°.\n"
            "z: ellipsoidal height, up in both frames.",
            fontsize=11, va="top")
    ax.set_xlim(-1.2, 5.8)
    ax.set_ylim(-2.6, 3.5)


def main() -> None:
    plt.rcParams.update({"font.family": "DejaVu Sans", "mathtext.fontset": "dejavusans"})
    fig, axes = plt.subplots(1, 3, figsize=(20, 6.2), gridspec_kw={"width_ratios": [8.8, 8.7, 7.0]})
    for ax, draw in zip(axes, (top_view, side_view, world_view)):
        draw(ax)
        ax.set_aspect("equal")
        ax.set_anchor("N")
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(OUT, dpi=100, bbox_inches="tight", pad_inches=0.15, metadata={"Software": None})
    plt.close(fig)
    print(OUT)


if __name__ == "__main__":
    main()
