"""unlisted: the concealed courtyard drive (scenarios/concealed.py: sim6_turn, pitched head, 1 cm range noise)
with physics the mismatch finder has no candidate for, each modest against the noise and partly absorbed by
the ordinary calibration parameters. Every surface gets its own diffuse reflectivity (a seeded draw) and
painted patches (MARKINGS: a chequerboard of 1 m cells, every other one 70 % darker, as road markings, windows
and stains make real surfaces), so that the intensity (255 x reflectivity x |cos incidence|) is a regressor of
its own, not the incidence again, and varies along a surface as well as between surfaces.

UNLISTED[effect] gives the simulator's parameters and the channel and regressor of the discrepancy that
describes it; `effect=None` is the clean recording. `named` adds one of the finder's named candidates
(scenarios/concealed.py's CONCEALED) beside the unlisted effect.
"""

from dataclasses import dataclass

import numpy as np

from graphcal.simulation.scenario import Scenario
from graphcal.simulation.scene import Markings
from graphcal.simulation.script import load_scenario_builder, run_scenario_script

REFLECTIVITY = (0.08, 0.9)  # range of the surfaces' diffuse reflectivity
MARKINGS = Markings(cell_m=1.0, contrast=0.7)


@dataclass(frozen=True)
class Unlisted:
    """An unlisted effect's simulator parameters, its true curve's channel and regressor, and its curve:
    the channel's error (diagnosis.json's sign and unit) at a regressor value."""

    effects: dict
    channel: str
    regressor: str
    curve: object


UNLISTED = {
    "range_walk": Unlisted({"range_walk": {"walk_m": 0.025, "scale": 40.0}}, "range", "intensity",
                           lambda intensity: 0.025 * np.exp(-np.asarray(intensity) / 40.0)),
    "thermal_range_drift": Unlisted({"thermal_range_drift": {"drift_m": 0.02, "tau_s": 2.0}}, "range", "time",
                                    lambda t: 0.02 * (1.0 - np.exp(-np.asarray(t) / 2.0))),
    "head_wobble": Unlisted({"head_wobble": {"amplitude_deg": 0.06, "phase_deg": 20.0}}, "elevation", "azimuth",
                            lambda azimuth_deg: 0.06 * np.sin(2.0 * np.radians(azimuth_deg) + np.radians(20.0))),
    "firing_delay": Unlisted({"firing_delay": {"step_s": 6e-5}}, "time", "fibre",
                             lambda fibre: -6e-5 * np.asarray(fibre)),
}


def scenario(size: float = 1.0, seed: int = 0, effect: str | None = "range_walk", named: str | None = None) -> Scenario:
    """The concealed courtyard with one unlisted effect (None: clean), its surfaces' reflectivities drawn with
    the seed, and optionally one named candidate of scenarios/concealed.py beside it."""
    if effect is not None and effect not in UNLISTED:
        raise ValueError(f"unknown unlisted effect {effect!r}; known: {', '.join(UNLISTED)}")
    concealed = load_scenario_builder("concealed")
    base = concealed(size=size, seed=seed, effect=named)
    rng = np.random.default_rng(seed + 1000)
    scene = [obj.model_copy(update={"reflectivity": float(rng.uniform(*REFLECTIVITY))}) for obj in base.scene]
    spec = dict(base.effects) | (UNLISTED[effect].effects if effect else {})
    name = "unlisted-" + "+".join(n for n in (effect or "clean", named) if n)
    return base.model_copy(update={"name": name, "scene": scene, "markings": MARKINGS, "effects": spec})


if __name__ == "__main__":
    run_scenario_script(scenario)
