"""The first real calibration: the static HDL-32E recording (VeloView's monterey pcap) is calibrated
on what a static head determines, and the rest is named (docs/math.md "A static sensor")."""

from pathlib import Path

import numpy as np
import pytest

import graphcal
from graphcal.importers.velodyne_pcap import import_pcap

MONTEREY = Path(__file__).resolve().parents[2] / "shared/data/real/veloview_hdl32e_vlp16_pcap/monterey-first-100-packets.pcap"


@pytest.mark.skipif(not MONTEREY.is_file(), reason="shared real data absent")
def test_the_static_recording_is_calibrated_on_what_it_determines():
    recording = import_pcap(MONTEREY, quiet=True)
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="intrinsic", max_points=120_000), quiet=True)
    history = result.history
    # the pairs are made once: the energy cannot fall by dropping pairs as the fibres move
    assert len({row["pairs"] for row in history}) == 1 and history[0]["phase"] == "fine"
    assert history[-1]["energy_after_cm2"] <= history[0]["energy_cm2"]
    unobservable = set(result.unobservable)
    fibres = [f for f in range(recording.sensor.n_fibres) if f != recording.sensor.reference_fibre]
    for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg"):
        assert {f"fibre_{f}.{name}" for f in fibres} <= unobservable
    assert {"extrinsic.yaw_deg", "trajectory.common_translation"} <= unobservable
    estimated = [f for f in fibres if f"fibre_{f}.h_z_m" not in unobservable]
    # the upper fibres see only far objects and pair with nothing; the ground fibres' common height is not
    # tied to the reference fibre (0 deg, far objects only): most heights are held, a few may stay
    assert len(estimated) < len(fibres) // 2 and f"fibre_{recording.sensor.n_fibres - 1}.h_z_m" in unobservable
    hz_m = result.calibration.estimate.offsets[estimated, 3]
    assert np.all(np.abs(hz_m) < 0.05)  # centimetres, not the metres of a run that walks
    assert np.all(result.uncertainty.intrinsics[estimated, 3] <= 0.01)  # each determined to the 1 cm firm sigma
