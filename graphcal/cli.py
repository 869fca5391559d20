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
def calibrate(recording: Annotated[Path, typer.Argument(help="recording directory")],
              mode: Annotated[str, typer.Option(help="intrinsic, extrinsic, trajectory, joint, joint_trajectory, "
                                                     "extrinsic_then_intrinsic, intrinsic_then_extrinsic")] = "intrinsic",
              config: Annotated[Path | None, typer.Option(help="YAML file of CalibrationConfig settings")] = None,
              out: Annotated[Path | None, typer.Option(help="run folder (default runs/<name>-<UTC time>)")] = None,
              quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Self-calibrate a recording; writes calibration.yaml, config, history and residuals."""
    import datetime

    import pydantic

    from graphcal.calibration.calibrate import calibrate as run
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.errors import ConfigError
    from graphcal.recording import Recording
    from graphcal.yamlfile import read_yaml

    settings = (read_yaml(config) or {}) if config is not None else {}
    if not isinstance(settings, dict):
        raise ConfigError(f"{config}: not a mapping of CalibrationConfig settings (name: value per line)")
    try:
        chosen = CalibrationConfig(**{"mode": mode, **settings})
    except pydantic.ValidationError as error:
        first = error.errors()[0]
        raise ConfigError(f"{config or '--mode'}: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    rec = Recording.load(recording)
    result = run(rec, chosen, quiet=quiet)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    folder = out or Path("runs") / f"{rec.name}-{stamp}"
    path = result.save(folder, command=" ".join(["graphcal"] + sys.argv[1:]))
    if not quiet:
        before, after = result.energy_cm2
        typer.echo(f"J {before:.3g} -> {after:.3g} cm^2 in {result.seconds:.1f} s; wrote {path}")
        if result.unobservable:
            typer.echo(f"unobservable (held at nominal): {', '.join(result.unobservable)}")


@app.command()
@_clear_errors
def deskew(recording: Annotated[Path, typer.Argument(help="recording directory")],
           source: Annotated[str, typer.Option(help="motion during the sweep: ins, odometry, or none (raw scans)")] = "ins",
           cloud_format: Annotated[str, typer.Option("--format", help="ply, las, laz, or uos (3DTK .3d)")] = "ply",
           out: Annotated[Path | None, typer.Option(help="output folder (default out/<name>-deskew-<source>)")] = None,
           gyro: Annotated[bool, typer.Option(help="odometry: yaw from the gyro column when there is one")] = True,
           quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Deskew every revolution into its end-of-scan lidar frame (seed 002): one cloud and one 3DTK
    pose per revolution, poses.csv and deskew.yaml."""
    from graphcal.cloud_io import FORMATS
    from graphcal.deskewing import SOURCES, iter_scans
    from graphcal.errors import ConfigError
    from graphcal.recording import Recording
    from graphcal.scan_files import save_scans

    if source not in SOURCES:
        raise ConfigError(f"--source {source!r}: expected one of {', '.join(SOURCES)}")
    if cloud_format not in FORMATS:
        raise ConfigError(f"--format {cloud_format!r}: expected one of {', '.join(FORMATS)}")
    started = time.perf_counter()
    rec = Recording.load(recording)
    folder = out or Path("out") / f"{rec.name}-deskew-{source}"
    manifest = {"recording": str(recording), "source": source, "gyro": gyro, "crs": rec.world.crs.to_string()}
    save_scans(iter_scans(rec, source, use_gyro=gyro, quiet=quiet), folder, cloud_format, manifest)
    if not quiet:
        typer.echo(f"{len(rec.points):,} returns deskewed ({source}) into {folder} in "
                   f"{time.perf_counter() - started:.1f} s")


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
