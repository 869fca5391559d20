"""Starting points of seed 000's experiments: how far the true sensor lies from the nominal one.

PITCHED_HEAD: the head pitched 20 deg forward (spin axis tilted towards the driving direction)
as mobile mapping systems mount it, so that every fibre sweeps the road and the facades over a
span of ranges (level, each fibre sees the flat road at one range only).
TABLE_4_1: intrinsic errors on every fibre but the reference, within +-3 deg for the angles and
+-10 cm for range and Hz, with the RMS of Table 4.1 (10 cm, 2.5 deg, 3 deg, 10 cm); exact extrinsic.
SECTION_4_5_2: the start of the joint vs successive comparison (section 4.5.2): extrinsic off by
50/50/80 cm and 2.5/3/-2 deg (roll/pitch/yaw), intrinsics off by an RMS of 3 cm (range, Hz) and
0.3 deg (angles).
"""

from graphcal.simulation.scenario import ExtrinsicSpec, IntrinsicErrors

PITCHED_HEAD = ExtrinsicSpec(lever_arm_m=(0.8, 0.0, 1.9), boresight_deg=(20.0, 0.0, 90.0))
TABLE_4_1_ERRORS = IntrinsicErrors(range_m=0.10, azimuth_deg=3.0, elevation_deg=3.0, h_z_m=0.10,
                                   rms=(0.10, 2.5, 3.0, 0.10))
SECTION_4_5_2_ERRORS = IntrinsicErrors(range_m=0.05, azimuth_deg=0.5, elevation_deg=0.5, h_z_m=0.05,
                                       rms=(0.03, 0.3, 0.3, 0.03))
SECTION_4_5_2_HEAD = PITCHED_HEAD.model_copy(update={"error_lever_arm_m": (0.5, 0.5, 0.8),
                                                      "error_boresight_deg": (2.5, 3.0, -2.0)})
STARTS = {"table_4_1": (PITCHED_HEAD, TABLE_4_1_ERRORS), "section_4_5_2": (SECTION_4_5_2_HEAD, SECTION_4_5_2_ERRORS)}

# the priors that go with these starts: their nominal model is no factory calibration (3 deg and 10 cm off
# for Table 4.1, an extrinsic 80 cm and 3 deg off for section 4.5.2), so the nominal's stated uncertainty
# is wide; calibrate's defaults state a factory calibration's (2 cm, 0.2 deg; 10 cm, 1 deg)
# (CalibrationConfig's `priors` section)
FAR_START_PRIORS = {"intrinsic_range_m": 0.3, "intrinsic_angle_deg": 10.0, "extrinsic_lever_arm_m": 1.0,
                    "extrinsic_boresight_deg": 10.0}
