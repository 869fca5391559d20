"""Which model of a channel's structure a finding takes (diagnose.generic_if_better): the named winner, or a
generic discrepancy of its channel that explains the structure better; and a discrepancy that an eligible named
candidate explains gives way to it (diagnose.named_if_it_explains); from test figures made up here. And which
channel constant is solved beside a discrepancy (diagnose.solved_beside)."""

import numpy as np

from graphcal.calibration.config import PriorSettings
from graphcal.diagnosis.diagnose import generic_if_better, named_if_it_explains, refit_floor_cm2, solved_beside
from graphcal.diagnosis.score import CandidateTest

SIGMA0_M = 0.01


def _test(name: str, statistic: float, dof: int, explained_m: float, held_out_cm2: float = 0.99) -> CandidateTest:
    """A test whose held-out J [cm2] goes from 1 to held_out_cm2, its drop's standard error 0.001 cm2."""
    return CandidateTest(name, dof, statistic, 1e-20, statistic, np.zeros(dof), np.eye(dof), 0.0, 0.0, 0.0, 0.1, [],
                         (1.0, held_out_cm2), n_clusters=100, explained_rms_m=explained_m, sigma0_m=SIGMA0_M,
                         held_out_se_cm2=0.001)


RANGE_SCALE = _test("range_scale", 398.0, 1, 0.00062)
RANGE_TIME = "range~time/8/1:2:3:4:5:6:7"  # a discrepancy of the range against the time along the drive


def test_a_rival_of_the_channel_that_gains_and_explains_more_takes_the_finding():
    rival = _test(RANGE_TIME, 608.0, 8, 0.00084)
    assert not rival.significant(10) and rival.significant(10, floor_sigma0=0.01)  # below the discovery floor only
    assert generic_if_better(RANGE_SCALE, [RANGE_SCALE], [rival]) is rival


def test_the_named_winner_stays_against_weaker_or_foreign_rivals():
    explains_less = _test(RANGE_TIME, 608.0, 8, 0.0005)
    gains_less = _test(RANGE_TIME, 390.0, 8, 0.0009)  # BIC gain 390 - 8 ln 100 < 398 - ln 100
    other_channel = _test("elevation~time/8/1:2:3:4:5:6:7", 900.0, 8, 0.002)
    for rival in (explains_less, gains_less, other_channel):
        assert generic_if_better(RANGE_SCALE, [RANGE_SCALE], [rival]) is RANGE_SCALE
    unsigned = _test("time_offset", 398.0, 1, 0.00062)  # no channel and regressor of its own: never replaced
    assert generic_if_better(unsigned, [unsigned], [_test(RANGE_TIME, 608.0, 8, 0.00084)]) is unsigned


def test_the_own_regressors_discrepancy_needs_to_be_eligible_and_to_gain_more():
    own = _test("range~range/8/1:2:3:4:5:6:7", 600.0, 8, 0.0015)
    assert generic_if_better(RANGE_SCALE, [RANGE_SCALE, own]) is own
    weak = _test("range~range/8/1:2:3:4:5:6:7", 300.0, 8, 0.0015)
    assert generic_if_better(RANGE_SCALE, [RANGE_SCALE, weak]) is RANGE_SCALE


def test_a_discrepancy_that_finds_nothing_beyond_the_named_physics_leaves_it_named():
    """beyond(name): the discrepancy's test with the named winner in its base. A curve that holds the named
    function gains at least what it gains; the finding is discovered only where something is left."""
    own = _test("range~range/8/1:2:3:4:5:6:7", 600.0, 8, 0.0015)
    rival = _test(RANGE_TIME, 608.0, 8, 0.00084)
    nothing_left = _test("left", 9.0, 8, 0.00005)
    structure_left = _test("left", 250.0, 8, 0.0005)
    assert not nothing_left.significant(10, floor_sigma0=0.01) and structure_left.significant(10, floor_sigma0=0.01)
    for finding, eligible, rivals in ((own, [RANGE_SCALE, own], []), (rival, [RANGE_SCALE], [rival])):
        assert generic_if_better(RANGE_SCALE, eligible, rivals, lambda name: nothing_left, 10) is RANGE_SCALE
        assert generic_if_better(RANGE_SCALE, eligible, rivals, lambda name: structure_left, 10) is finding
    asked = []
    generic_if_better(RANGE_SCALE, [RANGE_SCALE], [rival], lambda name: asked.append(name) or structure_left, 10)
    assert asked == [RANGE_TIME]


def test_the_time_offset_gives_way_to_a_time_curve_with_a_shape():
    """A time curve is eligible only for its shape beyond the time offset (diagnose.shape_only): the shape is
    found first, the offset, the curve's mean, next."""
    offset = _test("time_offset", 900.0, 1, 0.003)
    shaped = _test("time~fibre/31/0:31", 700.0, 31, 0.002)
    assert generic_if_better(offset, [offset, shaped]) is shaped
    assert generic_if_better(offset, [offset]) is offset
    assert generic_if_better(offset, [offset, _test(RANGE_TIME, 700.0, 8, 0.002)]) is offset  # another channel's


def test_a_discrepancy_a_named_candidate_explains_gives_way_to_it():
    """beyond(discrepancy, named): the discrepancy's test with the named candidate in its base. Where some named
    candidate leaves it nothing, the one leaving least takes the finding (a latency's azimuth shift in the turns,
    discovered as the azimuth against the yaw rate, is the time offset, not the spin rate that also absorbs part of
    it); where each leaves structure and predicts the held-out data worse, the discrepancy stays; a named winner
    is never replaced."""
    curve = _test("azimuth~yaw_rate/8/1:2:3:4:5:6:7", 900.0, 8, 0.002, held_out_cm2=0.95)
    latency = _test("time_offset", 500.0, 1, 0.0015, held_out_cm2=0.97)
    spin = _test("spin_rate", 700.0, 1, 0.0016, held_out_cm2=0.96)
    left = {"time_offset": _test("left", 3.0, 8, 0.00002), "spin_rate": _test("left", 9.0, 8, 0.00005)}
    assert not any(t.significant(10, floor_sigma0=0.01) for t in left.values())
    assert named_if_it_explains(curve, [curve, spin, latency], lambda name, base: left[base], 10) is latency
    structure = _test("left", 400.0, 8, 0.0015)
    assert structure.significant(10)
    assert named_if_it_explains(curve, [curve, spin, latency], lambda name, base: structure, 10) is curve
    assert named_if_it_explains(curve, [curve], lambda name, base: left[base], 10) is curve  # no named eligible
    asked = []
    assert named_if_it_explains(latency, [curve, latency], lambda name, base: asked.append(base) or structure, 10) is latency
    assert not asked


def test_a_named_candidate_that_predicts_the_held_out_data_as_well_as_the_curve_takes_the_finding():
    """Structure left beyond the named candidate, but the named law alone predicts the held-out data within the
    curve's standard error (0.001 cm2) of it: the named physics is the finding, the rest is for the next round."""
    curve = _test("range~incidence/8/1:2:3:4:5:6:7", 1197.0, 8, 0.0019, held_out_cm2=0.9650)
    law = _test("incidence_range_bias", 1116.0, 1, 0.0019, held_out_cm2=0.9655)
    weaker = _test("range_scale", 40.0, 1, 0.0004, held_out_cm2=0.998)
    structure = _test("left", 82.0, 8, 0.00056, held_out_cm2=0.999)
    assert structure.significant(10, floor_sigma0=0.01)
    assert named_if_it_explains(curve, [curve, law, weaker], lambda name, base: structure, 10) is law
    worse = _test("incidence_range_bias", 1116.0, 1, 0.0019, held_out_cm2=0.9665)  # beyond the standard error
    assert named_if_it_explains(curve, [curve, worse, weaker], lambda name, base: structure, 10) is curve


def test_a_discrepancys_refit_must_lower_j_by_the_square_of_the_floor_it_passed():
    """sigma0 1 cm: a discovery (explains 1.5 mm, over the discovery floor of a tenth of sigma0) must lower J on
    the same pairs by (0.1 cm)^2; a rival that passed only the named candidates' floor (a hundredth) by
    (0.01 cm)^2."""
    discovery = _test("range~range/8/1:2:3:4:5:6:7", 600.0, 8, 0.0015)
    rival = _test(RANGE_TIME, 608.0, 8, 0.00084)
    assert discovery.significant(10) and not rival.significant(10)
    assert np.isclose(refit_floor_cm2(discovery, 10), 0.1 ** 2)
    assert np.isclose(refit_floor_cm2(rival, 10), 0.01 ** 2)


def test_a_curve_gets_its_channel_s_constant_beside_it_once_and_the_range_s_only_while_the_reference_is_fixed():
    """The range's constant is solved beside a range curve when nothing else holds it: not beside an elevation
    curve, not twice, and not when priors.reference_fibre estimates the reference fibre's range (that offset is the
    constant then). A time curve gets the latency beside it, whatever the reference fibre."""
    fixed, estimated = PriorSettings(reference_fibre="fixed"), PriorSettings()
    assert solved_beside(RANGE_TIME, (), fixed) == ("range_offset",)
    assert solved_beside(RANGE_TIME, ("range_offset",), fixed) == ()
    assert solved_beside(RANGE_TIME, (), estimated) == ()
    assert solved_beside("time~fibre/31/0:31", (), fixed) == solved_beside("time~fibre/31/0:31", (), estimated) == (
        "time_offset",)
    assert solved_beside("time~fibre/31/0:31", ("time_offset",), estimated) == ()
    assert solved_beside("elevation~azimuth/8/0:360", (), fixed) == ()
    assert solved_beside("range_scale", (), fixed) == ()


def test_a_refit_is_compared_with_its_control_on_both_fits_pairs():
    """Fit.compared_with: each fit's J is the mean of its J on its own pairs and on the other's (eq. 4.4 with the
    pairs' fixed normals and weights, summed here pair by pair): pairs made at one fit's estimate do not decide."""
    from graphcal.calibration.association import Correspondences
    from graphcal.diagnosis.fit import Fit

    rng = np.random.default_rng(0)
    points = [rng.normal(0.0, 0.3, (50, 3)), rng.normal(0.0, 0.3, (50, 3))]  # two fits' placements of 50 returns
    pairs = []
    for _ in range(2):
        normal = rng.normal(size=(40, 3))
        pairs.append(Correspondences(rng.integers(0, 50, 40), rng.integers(0, 50, 40),
                                     normal / np.linalg.norm(normal, axis=1, keepdims=True), rng.uniform(0.2, 1, 40)))
    control, refit = (Fit(None, None, None, None, p, None, q) for p, q in zip(points, pairs))

    def energy_cm2(placed, on):  # sum w d^2 / sum w, d the distance along the normal at p [m], in cm2
        total = sum(w * float(n @ (placed[i] - placed[j])) ** 2
                    for i, j, n, w in zip(on.index_p, on.index_m, on.normal, on.weight))
        return total / on.weight.sum() * 1e4

    without, with_it = control.compared_with(refit)
    assert np.isclose(without, 0.5 * (energy_cm2(points[0], pairs[0]) + energy_cm2(points[0], pairs[1])))
    assert np.isclose(with_it, 0.5 * (energy_cm2(points[1], pairs[0]) + energy_cm2(points[1], pairs[1])))
