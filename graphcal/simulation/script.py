"""Command-line entry shared by the scenario scripts in scenarios/: simulate, then save."""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from pydantic import ValidationError

from graphcal.common.errors import ConfigError
from graphcal.recording.points import PointTable
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.simulator import simulate_to

# the scenario scripts of scenarios/, shipped inside the package as graphcal.scenarios (pyproject.toml)
SCENARIOS_DIR = Path(importlib.util.find_spec("graphcal.scenarios").submodule_search_locations[0])


def load_scenario_builder(name_or_path: str) -> Callable[..., Scenario]:
    """The `scenario(size=, seed=)` function of a scenario script, by path or by name in scenarios/."""
    path = Path(name_or_path)
    if not path.suffix:
        path = SCENARIOS_DIR / f"{name_or_path}.py"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in SCENARIOS_DIR.glob("[!_]*.py")))
        raise ConfigError(f"{name_or_path}: no such scenario (a script path, or one of: {known})")
    spec = importlib.util.spec_from_file_location(f"graphcal_scenario_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as error:
        raise ConfigError(f"{path}: line {error.lineno}: {error.msg} (the scenario script does not parse)") from None
    except Exception as error:  # the script's own code failed as it was loaded
        raise ConfigError(f"{_where(path, error)}: {type(error).__name__}: {error} "
                          "(the scenario script failed as it was loaded)") from None
    if not hasattr(module, "scenario"):
        raise ConfigError(f"{path}: a scenario script must define scenario(size=..., seed=...)")
    return module.scenario


def built(build: Callable[..., Scenario], **settings) -> Scenario:
    """build(**settings): the scenario a script's scenario() gives, or ConfigError naming the script (and the line
    where its code failed) when it fails or gives something other than a Scenario. A setting out of range is
    pydantic's ValidationError, which names the field."""
    path = Path(build.__code__.co_filename)
    try:
        scenario = build(**settings)
    except (ConfigError, ValidationError):
        raise
    except Exception as error:  # the script's own code failed
        raise ConfigError(f"{_where(path, error)}: {type(error).__name__}: {error} "
                          "(the scenario script's scenario() failed)") from None
    if not isinstance(scenario, Scenario):
        raise ConfigError(f"{path}: scenario() gave a value of type {type(scenario).__name__}, expected a graphcal Scenario")
    return scenario


def _where(path: Path, error: Exception) -> str:
    """path, with the line of the script where error was raised when it was raised there."""
    line = next((frame.lineno for frame in reversed(traceback.extract_tb(error.__traceback__))
                 if Path(frame.filename) == path), None)
    return f"{path}{f': line {line}' if line else ''}"


def run_scenario_script(build: Callable[..., Scenario], argv: list[str] | None = None) -> Path:
    """Parse --out/--size/--seed/--quiet (and --duration, --traffic, --traffic-density when build takes
    duration_s, traffic, traffic_density), simulate build(size=, seed=[, duration_s=, ...]) and write the
    recording as it goes (simulate_to: flat memory)."""
    name = Path(inspect.getfile(build)).stem
    parser = argparse.ArgumentParser(description=(build.__doc__ or name).strip().splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out") / name, help="recording directory to write")
    parser.add_argument("--size", type=float, default=1.0, help="fraction of the sensor's firings kept (0-1]")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    if "duration_s" in inspect.signature(build).parameters:
        parser.add_argument("--duration", type=float, dest="duration_s", help="seconds of drive (the scenario's "
                            "default when not given)")
    if "traffic" in inspect.signature(build).parameters:
        parser.add_argument("--traffic", action="store_true", default=None, help="moving vehicles and pedestrians")
    if "traffic_density" in inspect.signature(build).parameters:
        parser.add_argument("--traffic-density", type=float, dest="traffic_density",
                            help="as many times the scenario's movers per minute (with --traffic)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = vars(parser.parse_args(argv))
    out, quiet = args.pop("out"), args.pop("quiet")
    started = time.perf_counter()
    simulate_to(built(build, **{key: value for key, value in args.items() if value is not None}), out, quiet=quiet)
    if not quiet:
        print(f"{len(PointTable.open(out / 'points.parquet')):,} returns written to {out} "
              f"in {time.perf_counter() - started:.1f} s")
    return out
