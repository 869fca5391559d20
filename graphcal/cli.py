"""`graphcal` command line. Bad input ends with one clear line and exit code 2."""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Target-free lidar self-calibration with a GTSAM factor graph.", no_args_is_help=True,
                  pretty_exceptions_enable=False)

def _clear_errors(command):
    """Turn graphcal's own errors into one line on stderr and exit code 2."""
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        from graphcal.errors import GraphcalError

        try:
            return command(*args, **kwargs)
        except GraphcalError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(2) from None
    return wrapper


@app.command()
@_clear_errors
def simulate(scenario: Annotated[str, typer.Argument(help="scenario name (sim6_turn, ...) or script path")],
             out: Annotated[Path | None, typer.Option(help="recording directory to write")] = None,
             size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 1.0,
             seed: Annotated[int, typer.Option(help="seed of every random draw")] = 0,
             quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Simulate a scenario and write its recording (with truth/)."""
    from graphcal.sim.script import load_scenario_builder
    from graphcal.sim.simulator import simulate as run

    build = load_scenario_builder(scenario)
    started = time.perf_counter()
    recording = run(build(size=size, seed=seed), quiet=quiet)
    out = out or Path("out") / recording.name
    recording.save(out)
    if not quiet:
        typer.echo(f"{len(recording.points):,} returns written to {out} in {time.perf_counter() - started:.1f} s")


@app.command()
@_clear_errors
def info(recording: Annotated[Path, typer.Argument(help="recording directory")]) -> None:
    """Validate a recording (every return, in batches) and summarise it."""
    from graphcal.recording import Recording

    rec = Recording.load(recording, validate=False)
    summary = rec.validate()
    world = rec.world
    typer.echo(f"{rec.name}: {summary.n_points:,} returns from a {rec.sensor.model} "
               f"({rec.sensor.n_fibres} fibres, reference {rec.sensor.reference_fibre}) over "
               f"{summary.time_max - summary.time_min:.2f} s")
    typer.echo(f"world frame {world.crs.to_string()}, grid scale factor {world.scale_factor.mean():.6f}, "
               f"meridian convergence {world.convergence_deg.mean():+.4f} deg")
    typer.echo(f"odometry: {'yes' if rec.odometry is not None else 'no'}; truth: "
               f"{'yes' if (recording / 'truth').is_dir() else 'no'}")


@app.command()
@_clear_errors
def demo(out: Annotated[Path, typer.Option(help="where to write the demo recording")] = Path("out/demo"),
         size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 1.0,
         quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Flagship demo: simulate sim6_turn and measure how blurred the nominal cloud is."""
    from graphcal.demo import run_demo

    run_demo(out, size=size, quiet=quiet)


def main() -> None:  # pragma: no cover - console entry
    sys.exit(app())
