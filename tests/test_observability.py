"""The dense marginals fallback agrees with gtsam.Marginals where both work."""

import gtsam
import numpy as np

from graphcal.calibration.observability import DenseMarginals


def test_dense_marginals_match_gtsam():
    rng = np.random.default_rng(0)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(1, gtsam.Pose3(gtsam.Rot3.Rodrigues(rng.normal(0, 0.3, 3)), rng.normal(0, 1, 3)))
    values.insert(2, rng.normal(0, 1, 3))
    values.insert(3, rng.normal(0, 1, 4))
    graph.add(gtsam.PriorFactorPose3(1, gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.1, 1, 6))))
    graph.add(gtsam.PriorFactorPoint3(2, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    values.insert(4, rng.normal(0, 1, 3))
    graph.add(gtsam.BetweenFactorPoint3(2, 4, np.ones(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    graph.add(gtsam.PriorFactorVector(3, np.zeros(4), gtsam.noiseModel.Gaussian.Covariance(np.diag([1, 2, 3, 4.0]) + 0.5)))
    reference, dense = gtsam.Marginals(graph, values), DenseMarginals(graph, values)
    for key in (1, 2, 3, 4):
        np.testing.assert_allclose(dense.marginalCovariance(key), reference.marginalCovariance(key), rtol=1e-9, atol=1e-12)


def test_dense_marginals_keep_an_ill_scaled_direction():
    """Information from 1e14 (a 0.1 um constraint) down to 1e-6 (a 1 km prior), as a sharp
    intrinsic next to a lever arm held by its prior: the weak variance must survive."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(1, np.zeros(3))
    values.insert(2, np.zeros(3))
    graph.add(gtsam.PriorFactorPoint3(1, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-7)))
    graph.add(gtsam.PriorFactorPoint3(2, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e3)))
    graph.add(gtsam.BetweenFactorPoint3(1, 2, np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-7, 1e-7, 1e9]))))
    reference, dense = gtsam.Marginals(graph, values), DenseMarginals(graph, values)
    for key in (1, 2):
        np.testing.assert_allclose(dense.marginalCovariance(key), reference.marginalCovariance(key), rtol=1e-6, atol=1e-20)
