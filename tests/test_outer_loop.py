"""The outer loop's stopping rule on a J curve that has stopped falling (graphcal.calibration.solve.on_plateau)."""

from graphcal.calibration.solve import on_plateau

# fine-phase J [cm^2] of sim6_turn at full size, joint_trajectory (session 7 benchmark): it stops
# falling near 0.001 while the association's jitter keeps the largest step above tolerance_m
FULL_SIZE_FINE = [0.00111, 0.00111, 0.00101, 0.00100, 0.00099, 0.00098, 0.00099, 0.00099, 0.00104, 0.00104,
                  0.00101, 0.00101, 0.00098, 0.00099, 0.00099, 0.00099, 0.00097]


def first_stop(energies, iterations=6, improvement=0.01):
    return next((n for n in range(1, len(energies) + 1) if on_plateau(energies[:n], iterations, improvement)), None)


def test_a_curve_still_falling_does_not_stop():
    assert first_stop([0.95 ** k for k in range(30)]) is None
    # 0.1 % per iteration: six iterations fall 0.6 %, less than the 1 % a new low needs
    assert first_stop([0.999 ** k for k in range(30)]) == 7


def test_a_flat_jittering_curve_stops_once_no_new_low_came_in_the_window():
    # new lows (by 1 %) at the 3rd and 6th values; six values without one after the 6th: stop at the 12th
    assert first_stop(FULL_SIZE_FINE) == 12
    assert first_stop(FULL_SIZE_FINE, iterations=20) is None


def test_too_few_iterations_never_stop():
    assert not on_plateau([1.0] * 6, 6, 0.01)
    assert on_plateau([1.0] * 7, 6, 0.01)
