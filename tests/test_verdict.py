"""The one-line verdict on what a drive cannot observe (graphcal.calibration.verdict), from the names and reasons a
calibration gives and what the vehicle did; the degenerate drives' own names come from test_degenerate_drives.py
(a straight drive, a turn on the spot, a flat plain, a standstill), test_calibration.py (a straight drive) and
test_static_calibration.py (a static head)."""

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.calibration.observability import EXTRINSIC_NAMES, TRAJECTORY_GAUGE
from graphcal.calibration.verdict import RIGID_REASON, Motion, verdict

FIBRES = [f"fibre_{f}" for f in range(32) if f != 15]
STRAIGHT = Motion(travelled=True, turned=False, tilted=False)
TURNING = Motion(travelled=True, turned=True, tilted=False)
ON_THE_SPOT = Motion(travelled=False, turned=True, tilted=False)


def test_nothing_beyond_the_common_motion_gives_no_verdict():
    assert verdict(list(TRAJECTORY_GAUGE), {}, STRAIGHT) is None
    assert verdict([], {}, STRAIGHT) is None


def test_a_standstill_says_static_sensor_and_counts_the_held_intrinsics():
    extrinsic = [f"extrinsic.{name}" for name in EXTRINSIC_NAMES]
    intrinsic = [f"{fibre}.{kind}" for fibre in FIBRES for kind in ("d_range_m", "d_elevation_deg", "h_z_m")]
    reasons = {name: RIGID_REASON for name in extrinsic} | {name: "held" for name in intrinsic}
    line = verdict(intrinsic + extrinsic + list(TRAJECTORY_GAUGE), reasons, Motion(False, False, False))
    assert line.startswith("static sensor: the extrinsic and the trajectory are unobservable; 93 intrinsic "
                           "parameters held")


def test_a_flat_plain_names_the_heights_and_the_scene_that_would_show_them():
    """A drive with turns over a plain with no facades: each fibre's height trades with its range offset on the
    ground, and the horizontal axes of the extrinsic need upright surfaces, which more turns would not give."""
    names = [f"{fibre}.h_z_m" for fibre in FIBRES[:20]] + ["fibre_3.d_range_m", "extrinsic.lever_arm_x_m",
                                                           "extrinsic.lever_arm_z_m"]
    line = verdict(names, {name: "seen only in combination with ..." for name in names}, TURNING)
    assert line.startswith("this drive cannot observe the lever arm x (facades or poles beside the road, not only flat "
                           "ground, would show it); the lever arm z (a drive with slopes or banked turns")
    assert "20 fibre heights and 1 fibre range offset (fibres that see surfaces at several ranges" in line
    assert line.count(";") == 2


def test_axes_shown_by_the_same_manoeuvre_are_named_together():
    """On a straight drive the lever arm in the plane and the boresight roll are all shown by turns: one clause for
    the three."""
    names = ["extrinsic.roll_deg", "extrinsic.lever_arm_x_m", "extrinsic.lever_arm_y_m"]
    line = verdict(names, {}, STRAIGHT)
    assert line == ("this drive cannot observe the boresight roll, lever arm x and lever arm y (a drive with turns would "
                    "show them): held at nominal or bound by the prior")


def test_a_turn_on_the_spot_asks_for_a_drive_along_a_road():
    """Turning on the spot shows the lever arm in the plane but not the boresight yaw (turning the extrinsic about
    the vertical turns the whole cloud about the turning axis), nor the fibres from other places."""
    line = verdict(["extrinsic.yaw_deg", "fibre_3.h_z_m"], {}, ON_THE_SPOT)
    assert line == ("this drive cannot observe the boresight yaw (a drive along a road would show it); 1 fibre height "
                    "(a drive past facades, each surface seen from many places, would show them): held at nominal or "
                    "bound by the prior")


def test_the_motion_of_a_drive_from_its_poses():
    """Travelled: positions spanning 1 m or more; turned: a heading spanning 45 deg or more (unwrapped: a full turn
    on the spot spans 360 deg); tilted: the up axis swinging 2 deg or more."""
    n = 200
    still = np.zeros((n, 3))
    line = np.column_stack([np.linspace(0, 30, n), np.zeros(n), np.zeros(n)])
    heading_deg = np.linspace(0, 400, n)
    level_turn = Rotation.from_euler("z", heading_deg[:, None], degrees=True).as_matrix()
    level = np.broadcast_to(np.eye(3), (n, 3, 3))
    banked = Rotation.from_euler("zx", np.column_stack([heading_deg, np.linspace(0, 3, n)]), degrees=True).as_matrix()
    assert Motion.of(level, line) == STRAIGHT
    assert Motion.of(level_turn, still) == ON_THE_SPOT
    assert Motion.of(level, still) == Motion(travelled=False, turned=False, tilted=False)
    assert Motion.of(banked, line) == Motion(travelled=True, turned=True, tilted=True)
