"""`graphcal export`: a calibration run's intrinsics in a vendor's calibration format (graphcal/exporters)."""

from __future__ import annotations

from pathlib import Path


def export_run(run: Path, export_format: str, out: Path, original: Path | None = None) -> list[str]:
    """Write the calibrated intrinsics of a calibration run folder (or its calibration.yaml) to out in
    export_format, starting from the unit's original file when given; returns the notes. The sensor is the
    nominal model of the recording named in the run's run.yaml. Bad input fails before anything is written."""
    from graphcal.calibration.result import Calibration, calibration_file
    from graphcal.common.errors import ConfigError, RecordingError
    from graphcal.common.run_folder import MANIFEST
    from graphcal.common.yamlfile import read_yaml
    from graphcal.exporters import WRITERS, exported_offsets, read_original
    from graphcal.recording.directory import Recording

    if export_format not in WRITERS:
        raise ConfigError(f"--format {export_format!r}: expected one of {', '.join(WRITERS)}")
    if out.exists():
        raise ConfigError(f"--out {out}: already exists; export does not replace a file (remove it or choose "
                          "another --out)")
    path = calibration_file(run)
    if not path.is_file():
        raise RecordingError(path, "file not found", expected="a calibration run folder (graphcal calibrate's)")
    manifest = read_yaml(path.parent / MANIFEST)
    recording = manifest.get("recording") if isinstance(manifest, dict) else None
    if not isinstance(recording, str) or not recording:
        raise RecordingError(path.parent / MANIFEST, f"recording is {recording!r}", field="recording",
                             expected="the path of the calibrated recording")
    sensor = Recording.load(recording, validate=False).sensor
    calibration = Calibration.load(path, sensor)
    offsets, notes = exported_offsets(calibration.estimate.offsets, calibration.unobservable, calibration.held)
    unit = None
    if original is not None:
        unit, differences = read_original(export_format, original, sensor)
        notes += differences
    try:
        return notes + WRITERS[export_format](out, sensor, offsets, unit)
    except ConfigError as error:  # the writers see the original's text: say which file it is
        if original is None:
            raise
        raise ConfigError(f"--from {original}: {error}") from None
