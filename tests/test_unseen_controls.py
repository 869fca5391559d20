"""unseen_controls.py: the posterior sigmas of the control corrections against a dense inverse of the same
precision written out by hand, and which components a stretch without structure gets named for."""

import numpy as np
import pytest

from graphcal.calibration.unseen_controls import posterior_sigmas, unseen_controls

SIGMA_M = 0.006  # E_def's term


def _information(controls: int, blind: range, rng) -> np.ndarray:
    """Per-control data information [m^-2]: every control sees y and z well and x a little, those in `blind`
    see only z (a stretch of open ground)."""
    information = np.zeros((controls, 3, 3))
    for c in range(controls):
        a = rng.normal(size=(3, 3))
        information[c] = np.diag([4e4, 1e6, 1e6]) + 1e3 * a @ a.T
        if c in blind:
            information[c] = np.diag([0.0, 0.0, 1e6])
    return information


@pytest.mark.parametrize("deformation", ["prior", "monnier"])
def test_posterior_sigmas_are_the_dense_inverse(deformation):
    rng = np.random.default_rng(3)
    information = _information(12, range(4, 9), rng)
    n = 12 * 3
    precision = np.zeros((n, n))
    for c in range(12):
        precision[3 * c:3 * c + 3, 3 * c:3 * c + 3] += information[c]
    rigidity = np.eye(12) if deformation == "prior" else np.eye(12) / 12
    if deformation == "monnier":
        for c in range(1, 12):
            rigidity[np.ix_([c - 1, c], [c - 1, c])] += [[1, -1], [-1, 1]]
    precision += np.kron(rigidity, np.eye(3)) / SIGMA_M ** 2
    expected = np.sqrt(np.diag(np.linalg.inv(precision))).reshape(12, 3)
    np.testing.assert_allclose(posterior_sigmas(information, SIGMA_M, deformation), expected, rtol=1e-9)


def test_a_long_blind_stretch_is_named_along_the_ground_a_short_one_only_under_the_prior():
    """Five controls that see only the ground's normal: under eq. 5.3 each is known to E_def's sigma in x and y
    (named when above the 1 cm noise); under Monnier's differences the middle of the stretch is known to about
    sigma sqrt(k / 4) from the seen streets on each side (less with the anchors of sigma sqrt(C) on each control),
    so five controls at 0.6 cm stay unnamed and forty are named, their ends less than their middle. Height is seen
    everywhere."""
    rng = np.random.default_rng(4)
    times = np.arange(60.0)
    short = _information(60, range(20, 25), rng)
    assert unseen_controls(short, times, SIGMA_M, "monnier", 0.01) == {}
    assert set(unseen_controls(short, times, 0.02, "prior", 0.01)) == {
        f"control_{c}.{axis}" for c in range(20, 25) for axis in ("x_m", "y_m")}
    long = _information(60, range(10, 50), rng)
    named = unseen_controls(long, times, SIGMA_M, "monnier", 0.01)
    controls = sorted({int(name.split(".")[0].split("_")[1]) for name in named})
    assert not any(name.endswith(".z_m") for name in named)
    assert controls and 10 < controls[0] and controls[-1] < 49
    assert set(controls) == set(range(controls[0], controls[-1] + 1))
    assert "only along z_m" in named[f"control_{controls[0]}.x_m"]
    sigmas = posterior_sigmas(long, SIGMA_M, "monnier")[:, 0]
    assert sigmas[30] > sigmas[controls[0]] > 0.01 > sigmas[controls[0] - 1]
    assert sigmas[30] < SIGMA_M * np.sqrt(41 / 4)  # the bridge's middle, without the anchors
