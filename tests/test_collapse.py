"""The energy's trivial minimum (fibres collapsed onto one cone): refused, and avoided on a static sensor."""

import numpy as np
import pytest

from graphcal.calibration.checks import check_energy_fell, check_fibres_apart
from graphcal.calibration.config import COARSE_PLANE_DISTANCE_M, CalibrationConfig, held_names
from graphcal.common.errors import CalibrationError, ConfigError
from graphcal.recording.sensor import sensor_from_catalog
from graphcal.simulation.scenario import draw_offsets
from graphcal.simulation.starts import TABLE_4_1_ERRORS


def test_table_4_1_offsets_are_not_a_collapse():
    sensor = sensor_from_catalog("HDL-32E")
    for seed in range(5):  # the seed's largest start: 3 deg errors on a 1.33 deg fibre spacing
        offsets = draw_offsets(TABLE_4_1_ERRORS, sensor.n_fibres, sensor.reference_fibre, np.random.default_rng(seed))
        check_fibres_apart(sensor.elevation_deg, offsets[:, 2], "rec")


def test_fibres_pushed_onto_the_reference_are_refused():
    sensor = sensor_from_catalog("HDL-32E")
    reference = sensor.elevation_deg[sensor.reference_fibre]
    collapsed = np.radians(reference - sensor.elevation_deg) * 0.8  # 80 % of the way onto one cone
    with pytest.raises(CalibrationError, match="collapsed"):
        check_fibres_apart(sensor.elevation_deg, collapsed, "rec")


def test_a_static_sensor_holds_the_elevations_and_features_from_voxels():
    static, moving = CalibrationConfig().for_sensor(True, 0.0), CalibrationConfig().for_sensor(False, 0.0)
    assert static.features.voxel_m > 0 and moving.features.voxel_m == 0
    # a noisy head (range noise measured at 1 mm or more, or unknown): voxel features and pairs whitened along
    # their lines of sight; a noise-free one keeps every return's features and uniform pairs
    for noise_m in (0.01, np.nan):
        noisy_moving = CalibrationConfig().for_sensor(False, noise_m)
        assert noisy_moving.features.voxel_m > 0 and noisy_moving.weighting.pair_noise == "incidence"
    assert moving.weighting.pair_noise == "uniform" and moving.weighting.range_noise_m == 0.0
    chosen_noise = CalibrationConfig(weighting={"pair_noise": "uniform"}, features={"voxel_m": 0.0}).for_sensor(False, 0.01)
    assert chosen_noise.weighting.pair_noise == "uniform"
    assert moving.static.hold == () and static.static.hold == ("fibre_*.d_elevation_deg", "fibre_*.d_range_m",
                                                               "fibre_*.d_azimuth_deg", "fibre_*.h_z_m")
    assert static.static.hold_soft and static.static.check_halves and static.association.fixed
    assert not (moving.static.hold_soft or moving.static.check_halves or moving.association.fixed)
    held = held_names(static.static.hold, 32, 15)
    assert held == [f"fibre_{i}.{name}" for i in range(32) if i != 15
                    for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m")]
    chosen = CalibrationConfig(static={"hold": ()}, features={"voxel_m": 0.2}, association={"fixed": False}).for_sensor(True)
    assert chosen.static.hold == () and chosen.features.voxel_m == 0.2 and not chosen.association.fixed  # the user's


def test_hold_names_parameters_or_says_what_it_expected():
    assert held_names(("extrinsic.lever_arm_?_m", "fibre_3.h_z_m"), 32, 15) == [
        "fibre_3.h_z_m", "extrinsic.lever_arm_x_m", "extrinsic.lever_arm_y_m", "extrinsic.lever_arm_z_m"]
    with pytest.raises(ConfigError, match="'fibre_15.d_range_m' names no parameter"):  # the reference is fixed
        held_names(("fibre_15.d_range_m",), 32, 15)


def test_a_calibration_that_ends_above_its_start_is_refused():
    falling = [{"energy_cm2": 40.0, "energy_after_cm2": 5.0}, {"energy_cm2": 6.0, "energy_after_cm2": 0.01}]
    check_energy_fell(falling, "rec")
    gate_opened = [{"energy_cm2": 0.674, "energy_after_cm2": 0.6}, {"energy_cm2": 0.9, "energy_after_cm2": 0.866}]
    check_energy_fell(gate_opened, "rec")  # started at the truth: more pairs as the gate opens
    rising = [{"energy_cm2": 11.1, "energy_after_cm2": 5.2}, {"energy_cm2": 104.2, "energy_after_cm2": 103.9}]
    with pytest.raises(CalibrationError, match=r"diverged \(J 11.1 cm2 at the start, 104 cm2 at the end\)"):
        check_energy_fell(rising, "rec")


def test_a_hold_naming_nothing_is_refused_when_the_settings_are_read(tmp_path):
    from graphcal.cli.main import calibration_config

    settings = tmp_path / "settings.yaml"
    settings.write_text("static: {hold: ['fibre_*.d_elevation']}\n")  # the unit is missing
    with pytest.raises(ConfigError, match=r"settings.yaml: static.hold: .*'fibre_\*.d_elevation' names no parameter"):
        calibration_config("intrinsic", settings)


def test_crossed_rings_a_cap_and_a_slide_are_refused_with_what_slid():
    from graphcal.calibration.checks import check_converged, check_rings_in_order, check_within_priors, outside_priors
    from graphcal.calibration.weak_directions import Layout
    import gtsam

    sensor = sensor_from_catalog("HDL-32E")
    order = sensor.fibres_by_elevation()
    crossing = np.zeros(sensor.n_fibres)
    crossing[order[3]] = np.radians(1.5)  # 1.33 deg apart: above its upper neighbour
    check_rings_in_order(sensor.elevation_deg, np.zeros(sensor.n_fibres), 0.2, "rec")
    check_rings_in_order(sensor.elevation_deg, crossing, 10.0, "rec")  # a nominal model 10 deg off may cross
    # a nominal model further off than it states has crossed rings too: the fit then finds them crossed
    with pytest.raises(CalibrationError, match=rf"fibres {order[3]} and {order[4]} cross .* stated uncertainty "
                                               r"\(0.2 deg\) .* give its uncertainty \(priors.intrinsic_angle_deg\)"):
        check_rings_in_order(sensor.elevation_deg, crossing, 0.2, "rec")
    converged = [{"phase": "fine", "max_step": 1e-6, "stop": "converged"}]
    check_converged(converged, "rec")
    with pytest.raises(CalibrationError, match="did not converge: .* coarse phase"):
        check_converged([{"phase": "coarse", "max_step": 0.02, "stop": "cap"}], "rec")
    with pytest.raises(CalibrationError, match="did not converge: .* coarse phase"):  # the cap left no fine step
        check_converged([{"phase": "coarse", "max_step": 0.002, "stop": "coarse done"}], "rec")
    # a stage whose coarse phase stopped on the cap, though the fine phase run again (weak directions grown)
    # converged from there: refused, the cap named; an earlier stage's cap (a successive mode) is that stage's, and a
    # fine phase capped then run again to convergence had reached the basin
    capped = {"mode": "joint", "phase": "coarse", "max_step": 0.03, "stop": "cap", "energy_after_cm2": 0.34}
    again = {"mode": "joint, weak directions held", "phase": "fine", "max_step": 1e-6, "stop": "converged"}
    with pytest.raises(CalibrationError, match=r"did not converge: its coarse phase stopped on the cap after outer "
                                               r"iteration 1 \(J 0.34 cm²"):
        check_converged([capped, again], "rec")
    check_converged([capped | {"mode": "extrinsic"}, again], "rec")
    check_converged([capped | {"phase": "fine"}, again], "rec")  # a fine phase capped was in the basin: run again
    done = capped | {"mode": "joint, intrinsics held", "stop": "coarse done"}  # the coarse phase run again, done
    check_converged([capped, done, again], "rec")
    with pytest.raises(CalibrationError, match=r"coarse phase stalled \(J no longer falling, its step above the fine "
                                               r"phase's\) after outer iteration 1 \(J 0.34 cm²"):
        check_converged([capped | {"stop": "stalled"}, again], "rec")  # stalled, not run again: as the cap
    check_converged([capped | {"stop": "stalled"}, done, again], "rec")
    layout = Layout((1, 2), False, np.tile([0.02, np.radians(0.2), np.radians(0.2), 0.02], 2), np.eye(3))
    offsets = np.zeros((3, 4))
    offsets[2, 3] = 0.12  # 6 prior sigmas
    estimate = type("Estimate", (), {"offsets": offsets, "extrinsic": gtsam.Pose3()})
    check_within_priors(estimate, gtsam.Pose3(), layout, ["fibre_2.h_z_m"], "rec")  # named: the prior decides it
    with pytest.raises(CalibrationError, match=r"fibre_2.h_z_m \(6 sigmas\)"):
        check_within_priors(estimate, gtsam.Pose3(), layout, [], "rec")
    offsets[1, 2] = np.radians(-1.4)  # 7 prior sigmas: the furthest first
    far = outside_priors(estimate, gtsam.Pose3(), layout, [])
    assert [name for name, _ in far] == ["fibre_1.d_elevation_deg", "fibre_2.h_z_m"]
    assert np.allclose([z for _, z in far], [7.0, 6.0])


def test_a_coarse_phase_stalls_when_j_makes_no_new_low_at_its_full_gate():
    """The gate opening 0.3 m -> 1 m by 1.2 a step lets J rise with the pairs it admits: no stall while it opens,
    however J moves; at the full gate, six outer iterations without a low 1 % below the lowest before them stall the
    phase, a new low restarts the count, and the fine phase's rows are not counted."""
    from graphcal.calibration.problem import coarse_stalled

    gates = [min(0.3 * 1.2 ** k, 1.0) for k in range(30)]
    rows = lambda energies, phase="coarse": [{"phase": phase, "gate_m": g, "energy_cm2": e}  # noqa: E731
                                            for g, e in zip(gates, energies)]
    opening = [5.0, 4.0] + [4.5] * 5  # J rising while the gate opens (seven rows below 1 m)
    assert not coarse_stalled(rows(opening), 1.0, 6, 0.01)
    wandering = opening + [0.40, 0.36, 0.39, 0.37, 0.54, 0.44, 0.46, 0.38]  # a low at the second full-gate row
    assert not coarse_stalled(rows(wandering[:-1]), 1.0, 6, 0.01)  # five without a new low
    assert coarse_stalled(rows(wandering), 1.0, 6, 0.01)
    assert not coarse_stalled(rows(wandering[:-1] + [0.35]), 1.0, 6, 0.01)  # 0.35 < 0.99 x 0.36: a new low
    assert coarse_stalled(rows(wandering[:-1] + [0.357]), 1.0, 6, 0.01)  # 0.357: not 1 % below 0.36, stalled
    assert not coarse_stalled(rows(wandering, "fine"), 1.0, 6, 0.01)


def test_an_energy_the_noise_does_not_explain_is_refused():
    from graphcal.calibration.checks import check_energy_explained

    check_energy_explained(1.5, 1.2, 0.01, "rec")
    check_energy_explained(50.0, None, 0.01, "rec")  # no prediction: pairs whitened by a nominal sigma
    with pytest.raises(CalibrationError, match="J ends at 6 cm2 where the measured noise .* predicts 1.2 cm2"):
        check_energy_explained(6.0, 1.2, 0.01, "rec")


def test_auto_estimates_the_trajectory_only_where_the_drive_comes_back():
    from graphcal.calibration.returns import revisits
    from graphcal.recording.poses import PoseTrack

    t = np.arange(0.0, 60.0, 0.1)
    straight = np.column_stack([8.0 * t, np.zeros_like(t), np.zeros_like(t)])
    angle = 2 * np.pi * t / 40.0  # a 40 s loop of radius 40 m, driven one and a half times
    loop = np.column_stack([40 * np.cos(angle), 40 * np.sin(angle), np.zeros_like(t)])
    rpy = np.zeros((len(t), 3))
    assert not revisits(PoseTrack.from_rpy(t, straight, rpy))
    assert revisits(PoseTrack.from_rpy(t, loop, rpy))
    auto = CalibrationConfig()
    assert auto.for_sensor(False, 0.01, revisits=False).mode == "joint"
    assert auto.for_sensor(False, 0.01, revisits=True).mode == "joint_trajectory"
    assert auto.for_sensor(True, 0.01).mode == "intrinsic"
    # in place but turning (on the turning axis of a turn on the spot): the extrinsic estimated on pairs made again,
    # the intrinsics held and checked as a static sensor's (no parallax)
    spun = auto.for_sensor(False, 0.01, one_viewpoint=True)
    assert spun.mode == "joint" and not spun.association.fixed and spun.static.hold == auto.for_sensor(True).static.hold
    assert spun.static.hold_soft and spun.static.check_halves and spun.features.voxel_m == 0.1
    assert CalibrationConfig(mode="extrinsic").for_sensor(False, 0.01, revisits=True).mode == "extrinsic"


def test_the_coarse_plane_distance_gate_is_lifted_where_the_trajectory_is_estimated():
    """Trajectory corrections pair across an INS's steps (tests/test_trajectory_calibration.py: a 33 cm step is left
    uncorrected within 0.2 or 0.5 m of the plane), so the coarse phase's default gate holds only with the trajectory
    held; a gate the user sets is kept whatever the mode."""
    auto = CalibrationConfig()
    assert auto.association.coarse.max_plane_distance_m is None
    coarse = {mode: CalibrationConfig(mode=mode).for_sensor(False, 0.01).association.coarse.max_plane_distance_m
              for mode in ("joint", "intrinsic", "extrinsic_then_intrinsic", "trajectory", "joint_trajectory")}
    assert coarse == {"joint": COARSE_PLANE_DISTANCE_M, "intrinsic": COARSE_PLANE_DISTANCE_M,
                      "extrinsic_then_intrinsic": COARSE_PLANE_DISTANCE_M, "trajectory": np.inf,
                      "joint_trajectory": np.inf}
    assert auto.for_sensor(False, 0.01, revisits=True).association.coarse.max_plane_distance_m == np.inf
    set_by_user = CalibrationConfig(mode="joint_trajectory", association={"coarse": {"max_plane_distance_m": 0.4}})
    resolved = set_by_user.for_sensor(False, 0.01).association
    assert resolved.coarse.max_plane_distance_m == 0.4 and resolved.coarse.gate_max_m == 1.0
    assert resolved.fine.max_plane_distance_m == 0.05
    with pytest.raises(ValueError, match="association.fine.max_plane_distance_m: expected a distance in m"):
        CalibrationConfig(association={"fine": {"max_plane_distance_m": None}})


def test_a_coarse_phase_capped_with_the_trajectory_estimated_runs_again_with_the_intrinsics_held():
    """Trajectory corrections estimated beside the intrinsics, the coarse phase stopped on its cap: it runs again
    from the start with the intrinsics held at nominal (CalibrationPipeline), and the refusal judges that run's end.
    sim6_turn at size 0.02 with a cap of 2 outer iterations: both coarse runs capped (outer iterations 1-2, then
    3-4, the cap leaving the fine phase none): one coarse run alone would be refused after 2."""
    import graphcal
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim6_turn")(size=0.02, seed=0), quiet=True)
    stopping = {"max_outer_iterations": 2}
    with pytest.raises(CalibrationError, match=r"stopped after 4 outer iterations still in the coarse phase"):
        graphcal.calibrate(recording, CalibrationConfig(mode="joint_trajectory", stopping=stopping), quiet=True)


def test_a_calibration_interrupted_inside_the_coarse_phase_run_again_resumes_to_the_uninterrupted_one(tmp_path,
                                                                                                     monkeypatch):
    """The coarse phase run again with the intrinsics held (above), interrupted inside it and resumed from the
    checkpoint: the same outer iterations as the uninterrupted calibration (sim6_turn at size 0.02, a cap of 3)."""
    import graphcal
    from graphcal.calibration.checkpoint import Checkpoint
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim6_turn")(size=0.02, seed=0), quiet=True)
    config = CalibrationConfig(mode="joint_trajectory",
                               stopping={"max_outer_iterations": 3, "refuse_unconverged": False})
    uninterrupted = graphcal.calibrate(recording, config, quiet=True)
    assert any(row["mode"].endswith(", intrinsics held") for row in uninterrupted.history)
    save = Checkpoint.save

    def stopped_inside_the_run_again(self, state):
        save(self, state)
        if state.inside is not None and any(row["mode"].endswith(", intrinsics held") for row in state.rows):
            raise KeyboardInterrupt

    path = tmp_path / "checkpoint.npz"
    monkeypatch.setattr(Checkpoint, "save", stopped_inside_the_run_again)
    with pytest.raises(KeyboardInterrupt):
        graphcal.calibrate(recording, config, quiet=True, checkpoint=path)
    monkeypatch.setattr(Checkpoint, "save", save)
    resumed = graphcal.calibrate(recording, config, quiet=True, checkpoint=path)
    # the same steps (before the history's first coarse rows were read, it skipped the run again: 4 rows of 6);
    # the same figures to the checkpoint's round-off (the coarse phase's resume, test_trajectory_calibration.py)
    assert ([(row["mode"], row["phase"], row["stop"]) for row in resumed.history]
            == [(row["mode"], row["phase"], row["stop"]) for row in uninterrupted.history])
    np.testing.assert_allclose([row["energy_cm2"] for row in resumed.history],
                               [row["energy_cm2"] for row in uninterrupted.history], rtol=1e-6)
    for a, b in zip(resumed.calibration.estimate.corrections, uninterrupted.calibration.estimate.corrections):
        assert a.equals(b, 1e-7)
