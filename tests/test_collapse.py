"""A calibration whose fibres collapsed onto one cone (the energy's trivial minimum) is refused."""

import numpy as np
import pytest

from graphcal.calibration.calibrate import check_fibres_apart
from graphcal.errors import CalibrationError
from graphcal.sensor import sensor_from_catalog
from graphcal.sim.scenario import draw_offsets
from graphcal.sim.starts import TABLE_4_1_ERRORS


class _Recording:
    path, name = None, "rec"


def test_table_4_1_offsets_are_not_a_collapse():
    sensor = sensor_from_catalog("HDL-32E")
    for seed in range(5):  # the seed's largest start: 3 deg errors on a 1.33 deg fibre spacing
        offsets = draw_offsets(TABLE_4_1_ERRORS, sensor.n_fibres, sensor.reference_fibre, np.random.default_rng(seed))
        check_fibres_apart(sensor.elevation_deg, offsets[:, 2], _Recording())


def test_fibres_pushed_onto_the_reference_are_refused():
    sensor = sensor_from_catalog("HDL-32E")
    reference = sensor.elevation_deg[sensor.reference_fibre]
    collapsed = np.radians(reference - sensor.elevation_deg) * 0.8  # 80 % of the way onto one cone
    with pytest.raises(CalibrationError, match="collapsed"):
        check_fibres_apart(sensor.elevation_deg, collapsed, _Recording())
