"""The one-line verdict on what a drive cannot observe (graphcal.calibration.verdict), from the names and reasons a
calibration gives; the degenerate drives' own names come from test_calibration.py (a straight drive) and
test_static_calibration.py (a static head)."""

from graphcal.calibration.observability import EXTRINSIC_NAMES, TRAJECTORY_GAUGE
from graphcal.calibration.verdict import RIGID_REASON, verdict

FIBRES = [f"fibre_{f}" for f in range(32) if f != 15]


def test_nothing_beyond_the_common_motion_gives_no_verdict():
    assert verdict(list(TRAJECTORY_GAUGE), {}) is None
    assert verdict([], {}) is None


def test_a_standstill_says_static_sensor_and_counts_the_held_intrinsics():
    extrinsic = [f"extrinsic.{name}" for name in EXTRINSIC_NAMES]
    intrinsic = [f"{fibre}.{kind}" for fibre in FIBRES for kind in ("d_range_m", "d_elevation_deg", "h_z_m")]
    reasons = {name: RIGID_REASON for name in extrinsic} | {name: "held" for name in intrinsic}
    line = verdict(intrinsic + extrinsic + list(TRAJECTORY_GAUGE), reasons)
    assert line.startswith("static sensor: the extrinsic and the trajectory are unobservable; 93 intrinsic "
                           "parameters held")


def test_a_flat_plain_names_the_heights_and_the_scene_that_would_show_them():
    """A drive over a plain with no facades: each fibre's height trades with its range offset on the ground."""
    names = [f"{fibre}.h_z_m" for fibre in FIBRES[:20]] + ["fibre_3.d_range_m", "extrinsic.lever_arm_z_m"]
    line = verdict(names, {name: "seen only in combination with ..." for name in names})
    assert line.startswith("this drive cannot observe the lever arm z (a drive with slopes or banked turns")
    assert "20 fibre heights and 1 fibre range offsets (fibres that see surfaces at several ranges" in line
    assert line.count(";") == 1


def test_axes_shown_by_the_same_manoeuvre_are_named_together():
    """The lever arm in the plane and the boresight yaw are all shown by turns: one clause for the three."""
    names = ["extrinsic.lever_arm_x_m", "extrinsic.lever_arm_y_m", "extrinsic.yaw_deg"]
    line = verdict(names, {})
    assert line == ("this drive cannot observe the lever arm x, lever arm y and boresight yaw (a drive with turns would "
                    "show them): held at nominal or bound by the prior")
