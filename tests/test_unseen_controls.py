"""unseen_controls.py: which components of the control corrections are named from their reported 1-sigmas, and
what the reason says."""

import numpy as np

from graphcal.calibration.unseen_controls import unseen_controls

TIMES_S = np.array([100.0, 101.0, 102.0, 103.0])


def test_translation_components_above_the_noise_are_named_with_what_the_pairs_see():
    sigmas = np.full((4, 6), np.nan)  # translation-only corrections: no rotation sigmas
    sigmas[:, 3:] = [[0.002, 0.003, 0.001], [0.02, 0.004, 0.001], [0.05, 0.03, 0.002], [0.001, 0.001, 0.001]]
    reasons = unseen_controls(sigmas, TIMES_S, "monnier", 0.01)
    assert set(reasons) == {"control_1.x_m", "control_2.x_m", "control_2.y_m"}
    assert reasons["control_1.x_m"].startswith("too little structure near t = 101.0 s: the pairs there see the "
                                               "correction only along y_m, z_m; known to 2 cm")
    assert "only along z_m; known to 3 cm" in reasons["control_2.y_m"]
    assert reasons["control_2.x_m"].endswith("bound by the neighbouring controls (Monnier's differences)")
    assert unseen_controls(sigmas, TIMES_S, "prior", 0.06) == {}


def test_a_rotation_is_judged_in_rad_times_one_metre():
    """0.5 deg is 8.7 mm at 1 m: under a 1 cm threshold, above 5 mm; a control that sees nothing says so."""
    sigmas = np.full((4, 6), 0.001)
    sigmas[0, :3] = 0.5
    sigmas[3] = [1.0, 1.0, 1.0, 0.5, 0.5, 0.5]
    assert set(unseen_controls(sigmas, TIMES_S, "prior", 0.01)) == {f"control_3.{name}" for name in (
        "rotation_x_deg", "rotation_y_deg", "rotation_z_deg", "x_m", "y_m", "z_m")}
    named = unseen_controls(sigmas, TIMES_S, "prior", 0.005)
    assert {"control_0.rotation_x_deg", "control_0.rotation_z_deg"} <= set(named)
    assert not any(name.startswith(("control_1", "control_2")) for name in named)
    assert "along no direction" in named["control_3.x_m"] and "its prior (eq. 5.3)" in named["control_3.x_m"]
