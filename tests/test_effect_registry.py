"""One definition per effect (factors/effects.py): the mismatch finder's candidate basis is the first-order
inverse of the same effect's simulation hooks. For each simulated effect, the hooks' change of a return's
raw values, taken at the effect's own parameters, is undone by the candidate's channels at the matching
candidate parameters (range, time, heading and position hooks map the truth to what is recorded, so the
channel that restores the truth is minus their change; azimuth and horizontal-offset hooks map the
recorded value to the truth, so the channel is their change)."""

from pathlib import Path

import numpy as np
import pytest

from factors.channels import Context
from factors.effects import CANDIDATES, REGISTRY, SIMULATED, SOLVED_BESIDE, candidate
from factors.spherical import FactoryTerms
from graphcal.common.errors import ConfigError
from graphcal.simulation.effects import build_effects

N = 500
N_FIBRES = 8
SPIN_HZ = 10.0

# effect name -> (simulation parameters, the candidate parameters that stand for them)
MATCHING = {
    "intra_sweep_motion": ({"stamp": "revolution"}, [1.0]),
    "time_offset": ({"offset_s": 0.004}, [0.004]),
    "range_scale": ({"scale": 0.0015}, [0.0015]),
    "incidence_range_bias": ({"bias_m": 0.03}, [0.03]),
    "azimuth_eccentricity": ({"amplitude_deg": 0.06, "phase_deg": 35.0},
                             [np.radians(0.06) * np.cos(np.radians(35.0)), np.radians(0.06) * np.sin(np.radians(35.0))]),
    "heading_bias": ({"bias_deg": 0.3}, [np.radians(0.3)]),
    "heading_drift": ({"rate_deg_s": 0.02}, [np.radians(0.02)]),
    "projection_scale": ({"scale": 2e-4}, [2e-4]),
    "spin_rate": ({"error": 0.003}, [0.003]),
    "fibre_horizontal_offset": ({"offset_m": 0.004}, [0.004 if i % 2 == 0 else -0.004 for i in range(N_FIBRES)]),
    "range_offset": ({"offset_m": 0.013}, [0.013]),
}
# what the finder models: its candidates, and the channels' constants it solves beside a discrepancy
FINDER = CANDIDATES | {cls.name: cls for cls in SOLVED_BESIDE.values()}


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(11)
    t_rev = np.sort(rng.uniform(0, 10, N))
    sweep_s = rng.uniform(0, 1 / SPIN_HZ, N)
    xyz_m = np.cumsum(rng.normal(0, 0.5, (N, 3)), axis=0)
    context = Context(range_m=rng.uniform(2, 60, N), azimuth_rad=rng.uniform(0, 2 * np.pi, N),
                      fibre=rng.integers(0, N_FIBRES, N), n_fibres=N_FIBRES, sweep_s=sweep_s,
                      elapsed_s=t_rev + sweep_s - t_rev[0], cos_incidence=rng.uniform(0.05, 1, N),
                      X_nav=xyz_m - xyz_m[0])
    rpy_deg = rng.uniform(-180, 180, (N, 3))
    return context, t_rev, xyz_m, rpy_deg


def _hook_changes(effect, context, t_rev, xyz_m, rpy_deg) -> dict:
    """The change each hook makes to a return's values, in the channels' units (m, rad, s)."""
    t_fire = t_rev + context.sweep_s
    factory = FactoryTerms(np.zeros(N), horizontal_offset_m=np.zeros(N))
    return {
        "range": -(effect.measured_range(context.range_m, context.cos_incidence, None, context.elapsed_s) - context.range_m),
        "azimuth": effect.beam_azimuth(context.azimuth_rad) - context.azimuth_rad,
        "horizontal": effect.factory_terms(factory, context.fibre).horizontal_offset_m * np.ones(N),
        "time": -(effect.recorded_time(t_fire, t_fire, t_rev, context.fibre) - t_fire),
        "heading": -np.radians(effect.ins_rpy(context.elapsed_s, rpy_deg)[:, 2] - rpy_deg[:, 2]),
        "position": -(effect.ins_position(context.elapsed_s, xyz_m) - xyz_m),
    }


def _channels(basis, theta) -> dict:
    theta = np.asarray(theta, dtype=np.float64)
    out = {}
    for name in ("range", "azimuth", "horizontal", "time", "heading"):
        B = getattr(basis, name)
        out[name] = np.zeros(N) if B is None else B @ theta
    out["position"] = np.zeros((N, 3)) if basis.position is None else basis.position @ theta
    return out


@pytest.mark.parametrize("name", sorted(set(SIMULATED) & set(FINDER)))
def test_the_candidate_basis_undoes_the_simulation_hooks(scene, name):
    context, t_rev, xyz_m, rpy_deg = scene
    params, theta = MATCHING[name]
    effect = REGISTRY[name](**params)
    cls = candidate(name)
    assert cls is FINDER[name] and cls.dim(N_FIBRES) == len(theta)
    changes = _hook_changes(effect, context, t_rev, xyz_m, rpy_deg)
    channels = _channels(cls.basis(context), theta)
    for channel, change in changes.items():
        scale = max(np.abs(change).max(), np.abs(channels[channel]).max(), 1e-15)
        # first order: the azimuth's sinusoid and the range's scale are linear in the parameters, so equal to 1e-9
        np.testing.assert_allclose(channels[channel], change, atol=1e-9 * scale + 1e-15, err_msg=f"{name}: {channel}")
    assert cls.magnitude_of(np.asarray(theta)) == pytest.approx(abs(effect.magnitude()), rel=1e-9)


def test_every_effect_is_documented_once_for_both_uses():
    assert set(MATCHING) == set(SIMULATED) & set(FINDER)
    assert set(CANDIDATES) <= set(REGISTRY) and set(REGISTRY) - set(SIMULATED) == {"lever_arm"}
    for cls in REGISTRY.values():
        assert cls.__doc__ and cls.physics and cls.unit and cls.signature and cls.parameters


def test_the_finder_is_never_told_about_the_simulated_only_effects():
    """The effects with no candidate (what a real head carries that nobody listed) appear nowhere in the
    mismatch finder's code: it can only find them with its generic discrepancies."""
    unlisted = set(REGISTRY) - set(FINDER) - {"lever_arm"}
    assert len(unlisted) >= 4
    root = Path(__file__).resolve().parents[1]
    finder = sorted((root / "graphcal" / "diagnosis").glob("*.py")) + [root / "factors" / "discrepancy.py"]
    for path in finder:
        text = path.read_text()
        for name in unlisted:
            assert name not in text, f"{name} in {path}"
    for name in unlisted:
        with pytest.raises(KeyError):
            candidate(name)


def test_a_candidate_only_effect_is_refused_by_the_simulator_with_where_to_set_it():
    with pytest.raises(ConfigError, match="error_lever_arm_m"):
        build_effects({"lever_arm": {}})
