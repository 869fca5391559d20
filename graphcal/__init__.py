"""graphcal: target-free joint self-calibration of mobile-mapping lidar with a GTSAM factor graph.

The public names are imported on first use (PEP 562): `import graphcal` and the command line's
start-up (`graphcal --help`) do not load GTSAM, open3d and statsmodels until a command needs them.
"""

from importlib import import_module

__version__ = "0.1.0"
_HOMES = {"calibrate": "graphcal.calibration.calibrate",
          "CalibrationConfig": "graphcal.calibration.config",
          "Evaluation": "graphcal.calibration.evaluate", "apply_calibration": "graphcal.calibration.evaluate",
          "evaluate": "graphcal.calibration.evaluate",
          "Calibration": "graphcal.calibration.result", "CalibrationResult": "graphcal.calibration.result",
          "deskew": "graphcal.deskewing.deskew",
          "Diagnosis": "graphcal.diagnosis.diagnose", "diagnose": "graphcal.diagnosis.diagnose",
          "CalibrationError": "graphcal.common.errors", "ConfigError": "graphcal.common.errors", "GraphcalError": "graphcal.common.errors",
          "RecordingError": "graphcal.common.errors",
          "Recording": "graphcal.recording.directory",
          "SensorModel": "graphcal.recording.sensor", "sensor_from_catalog": "graphcal.recording.sensor",
          "Scenario": "graphcal.simulation.scenario",
          "simulate": "graphcal.simulation.simulator"}
__all__ = ["Calibration", "CalibrationConfig", "CalibrationError", "CalibrationResult", "ConfigError", "Diagnosis",
           "Evaluation", "GraphcalError", "Recording", "RecordingError", "Scenario", "SensorModel", "__version__",
           "apply_calibration", "calibrate", "deskew", "diagnose", "evaluate", "sensor_from_catalog", "simulate"]


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module 'graphcal' has no attribute {name!r}")
    value = getattr(import_module(_HOMES[name]), name)
    globals()[name] = value  # once
    return value


def __dir__() -> list[str]:
    return __all__
