"""The package's public names: each resolves, and importing graphcal (or its command line) loads none
of the heavy libraries until a name needs them."""

import subprocess
import sys

import graphcal


def test_every_public_name_resolves_to_its_home():
    for name in graphcal.__all__:
        assert getattr(graphcal, name) is not None, name
    assert graphcal.calibrate.__module__ == "graphcal.calibration.calibrate"
    assert graphcal.ConfigError.__module__ == "graphcal.common.errors"


def test_import_and_the_command_line_start_light():
    code = ("import sys, graphcal, graphcal.cli.main; "
            "print(sorted(m for m in ('gtsam', 'open3d', 'statsmodels', 'pyproj') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == "[]"


def test_pyproject_lists_every_package_of_the_tree():
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(path.parent.relative_to(root).parts) for top in ("graphcal", "factors")
             for path in (root / top).rglob("__init__.py")}
    assert found | {"graphcal.scenarios"} == listed


def test_the_installed_package_works_outside_the_checkout(tmp_path):
    """pip install of a built wheel (not editable) into a fresh virtual environment, its dependencies
    taken from this one: the command line runs from another folder and finds its scenarios."""
    import site
    import venv
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", str(root), "-w", str(wheels)],
                   check=True, capture_output=True)
    env = tmp_path / "env"
    venv.create(env)
    packages = next((env / "lib").glob("python*/site-packages"))
    (packages / "dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([str(env / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps",
                    str(next(wheels.glob("*.whl")))], check=True, capture_output=True)
    done = subprocess.run([str(env / "bin" / "graphcal"), "simulate", "sim2_street", "--size", "0.005", "--out",
                           str(tmp_path / "rec"), "-q"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "rec" / "points.parquet").is_file()
    where = subprocess.run([str(env / "bin" / "python"), "-c", "import graphcal; print(graphcal.__file__)"],
                           cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    assert str(root) not in where  # the installed copy, not the checkout
