"""The effects a scenario switches on: its `effects:` mapping validated against the registry of
factors.effects (one definition per effect), and what effects.yaml records of them."""

from __future__ import annotations

from pydantic import ValidationError

from factors.effects import REGISTRY, SIMULATED, Effect
from graphcal.common.errors import ConfigError

ON_BY_DEFAULT = ("intra_sweep_motion",)


def build_effects(spec: dict[str, dict | bool] | None) -> list[Effect]:
    """{'name': {params}} -> validated effects, in registry order (the order hooks compose).

    Effects of ON_BY_DEFAULT are added unless given as False; {'name': False} switches off.
    """
    spec = {**{name: {} for name in ON_BY_DEFAULT}, **(spec or {})}
    spec = {name: params for name, params in spec.items() if params is not False}
    candidates_only = sorted(set(spec) & (set(REGISTRY) - set(SIMULATED)))
    if candidates_only:
        raise ConfigError(f"effect(s) {candidates_only} are not simulated as effects: give the scenario's extrinsic "
                          f"an error (extrinsic.error_lever_arm_m) instead")
    unknown = sorted(set(spec) - set(SIMULATED))
    if unknown:
        raise ConfigError(f"unknown effect(s) {unknown}; known: {', '.join(SIMULATED)}")
    effects = []
    for name, cls in SIMULATED.items():
        if name in spec:
            try:
                params = spec[name]
                if params is not True and not isinstance(params, dict):
                    raise ConfigError(f"effect '{name}': {params!r} is neither parameters nor True/False")
                effects.append(cls(**(params if isinstance(params, dict) else {})))
            except ValidationError as error:
                raise ConfigError(f"effect '{name}': {error.errors()[0]['loc']} {error.errors()[0]['msg']}") from None
    return effects


def describe(effects: list[Effect]) -> dict:
    """What effects.yaml records: each switched-on effect with its parameters and magnitude."""
    return {e.name: {**e.model_dump(), "magnitude": float(e.magnitude()), "unit": e.unit, "physics": e.physics}
            for e in effects}
