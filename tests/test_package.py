"""The package's public names: each resolves, and importing graphcal (or its command line) loads none
of the heavy libraries until a name needs them."""

import subprocess
import sys

import graphcal


def test_every_public_name_resolves_to_its_home():
    for name in graphcal.__all__:
        assert getattr(graphcal, name) is not None, name
    assert graphcal.calibrate.__module__ == "graphcal.calibration.calibrate"
    assert graphcal.ConfigError.__module__ == "graphcal.errors"


def test_import_and_the_command_line_start_light():
    code = ("import sys, graphcal, graphcal.cli; "
            "print(sorted(m for m in ('gtsam', 'open3d', 'statsmodels', 'pyproj') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == "[]"
