"""The outer loop: its stopping rule on a J curve that has stopped falling (on_plateau), and its
Levenberg-Marquardt on a badly scaled graph (levenberg_marquardt)."""

import gtsam
import numpy as np
import pytest

from graphcal.calibration.solve import HELD_SIGMA, levenberg_marquardt, on_plateau

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


def _overshooting_graph():
    """x0 held at 0 by a HELD_SIGMA prior (information 1e14) and x1 with residual tanh(x1) - 0.5 at a
    sigma of 1e-6 from x1 = 3, where tanh is flat: the Gauss-Newton step (about -50) lands where the
    residual is larger (tanh = -1), and lambda must reach ~1e9 to shorten it enough."""
    def residual(_, values, jacobians):
        x = values.atVector(1)[0]
        if jacobians is not None:
            jacobians[0] = np.array([[1.0 - np.tanh(x) ** 2]])
        return np.array([np.tanh(x) - 0.5])

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(0, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, HELD_SIGMA)))
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, 1e-6), [1], residual))
    values = gtsam.Values()
    values.insert(0, np.zeros(1))
    values.insert(1, np.array([3.0]))
    return graph, values


def test_lm_steps_where_the_default_damping_cannot():
    graph, values = _overshooting_graph()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(20)
    stuck = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    assert stuck.atVector(1)[0] == 3.0  # GTSAM's default: every lambda up to 1e5 rejected
    solved = levenberg_marquardt(graph, values, 20)
    assert np.tanh(solved.atVector(1)[0]) == pytest.approx(0.5, abs=1e-9)
    assert solved.atVector(0)[0] == 0.0
