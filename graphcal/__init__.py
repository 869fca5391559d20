"""graphcal: target-free joint self-calibration of mobile-mapping lidar with a GTSAM factor graph."""

from graphcal.calibration.calibrate import calibrate
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.evaluate import Evaluation, apply_calibration, evaluate
from graphcal.calibration.result import Calibration, CalibrationResult
from graphcal.deskewing import deskew
from graphcal.diagnosis.diagnose import Diagnosis, diagnose
from graphcal.errors import CalibrationError, ConfigError, GraphcalError, RecordingError
from graphcal.recording import Recording
from graphcal.sensor import SensorModel, sensor_from_catalog
from graphcal.sim.scenario import Scenario
from graphcal.sim.simulator import simulate

__version__ = "0.1.0"
__all__ = [
           "Calibration",
           "CalibrationConfig",
           "CalibrationError",
           "CalibrationResult",
           "ConfigError",
           "Diagnosis",
           "Evaluation",
           "GraphcalError",
           "Recording",
           "RecordingError",
           "Scenario",
           "SensorModel",
           "__version__",
           "apply_calibration",
           "calibrate",
           "deskew",
           "diagnose",
           "evaluate",
           "sensor_from_catalog",
           "simulate",
]
