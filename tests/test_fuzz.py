"""Fuzzing every reader of the recording contract and of calibration.yaml, through the command line, with
seeded mutations of a valid recording and calibration: bit flips, truncation, empty files, missing files,
directories for files, binary garbage, and in the text files NaN, inf, huge, negative and non-numeric values,
deleted, duplicated and swapped lines; in points.parquet, columns rewritten NaN, negative, out of range,
unsorted, duplicated or of the wrong type.

Every case must end in a clean refusal (exit 2, one line naming the file) or a run that goes on (exit 0); never a
traceback (exit 1), and no NumPy RuntimeWarning (an overflow or invalid value computed from input that should
have been refused first). A recording `graphcal info` accepts must then be read by a calibration's reader without a
traceback, and a calibration.yaml `Calibration.load` accepts must place 2000 of the recording's returns at
finite points. Every importer gets its own small input with one file mutated: a clean refusal, or a recording
`graphcal info` accepts. The counts per category are printed (pytest -s) and checked against MIN_CASES.
"""

from __future__ import annotations

import collections
import re
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import typer
import typer.testing
from typer.testing import CliRunner

import graphcal
from graphcal.cli.main import app
from graphcal.common.errors import GraphcalError

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

MIN_CASES = 1000  # recordings and calibration.yaml files; with IMPORT_CASES per importer, over 1000 a run
RECORDING_CASES = 650  # through `graphcal info` and a calibration's reader; the rest are calibration.yaml files
TEXT_FILES = ("recording.yaml", "sensor.yaml", "extrinsic.yaml", "trajectory.csv")
NUMBER = re.compile(rb"-?\d+\.?\d*(?:e-?\d+)?")
HOSTILE_NUMBERS = (b"nan", b"NaN", b"inf", b"-inf", b"1e308", b"-1e308", b"9e12", b"-1", b"0", b"abc", b"",
                   b"1e-320", b"'", b"[]", b"{a: 1}")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A small valid recording (some 20 000 returns) and a calibration.yaml of it (one outer iteration)."""
    from graphcal.simulation.script import load_scenario_builder

    root = tmp_path_factory.mktemp("fuzz")
    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.005, seed=3), quiet=True)
    path = recording.save(root / "rec")
    shutil.rmtree(path / "truth")
    config = graphcal.CalibrationConfig(mode="intrinsic", stopping={"max_outer_iterations": 1,
                                                                    "refuse_unconverged": False})
    graphcal.calibrate(graphcal.Recording.load(path), config, quiet=True).save(root / "cal")
    return path, root / "cal" / "calibration.yaml"


def _text_mutation(data: bytes, rng: np.random.Generator) -> bytes:
    lines = data.split(b"\n")
    kind = rng.integers(6)
    if kind == 0:  # a number made hostile
        numbers = list(NUMBER.finditer(data))
        if numbers:
            hit = numbers[rng.integers(len(numbers))]
            return data[:hit.start()] + HOSTILE_NUMBERS[rng.integers(len(HOSTILE_NUMBERS))] + data[hit.end():]
    if kind == 1 and len(lines) > 1:  # a line deleted
        del lines[rng.integers(len(lines))]
    elif kind == 2 and len(lines) > 1:  # a line duplicated
        k = rng.integers(len(lines))
        lines.insert(k, lines[k])
    elif kind == 3 and len(lines) > 2:  # two lines swapped (unsorted times in a table)
        a, b = rng.choice(len(lines), 2, replace=False)
        lines[a], lines[b] = lines[b], lines[a]
    elif kind == 4:  # a key misspelt
        keys = [m for m in re.finditer(rb"^(\s*-?\s*)([a-z_]+):", data, re.M)]
        if keys:
            hit = keys[rng.integers(len(keys))]
            return data[:hit.start(2)] + hit.group(2)[::-1] + data[hit.end(2):]
    else:
        return _bytes_mutation(data, rng)
    return b"\n".join(lines)


def _bytes_mutation(data: bytes, rng: np.random.Generator) -> bytes:
    kind = rng.integers(4)
    if kind == 0 and data:  # bit flips
        out = bytearray(data)
        for k in rng.integers(len(out), size=rng.integers(1, 8)):
            out[k] ^= 1 << int(rng.integers(8))
        return bytes(out)
    if kind == 1:  # truncated
        return data[:rng.integers(len(data) + 1)]
    if kind == 2:
        return b""
    return rng.integers(256, size=rng.integers(1, 400)).astype(np.uint8).tobytes()  # binary garbage


def _points_mutation(path: Path, rng: np.random.Generator) -> str:
    """Rewrite points.parquet with one column made hostile; returns what was done."""
    table = pq.read_table(path)
    columns = {name: table.column(name).to_numpy().copy() for name in table.column_names}
    name = str(rng.choice(list(columns)))
    values = columns[name]
    kind = int(rng.integers(6))
    rows = rng.choice(len(values), min(len(values), int(rng.integers(1, 20))), replace=False)
    if kind == 0 and values.dtype.kind == "f":
        values[rows] = rng.choice([np.nan, np.inf, -np.inf])
    elif kind == 1:
        values[rows] = -values[rows] - 1
    elif kind == 2:
        values[rows] = values.max() * 1e6 if values.dtype.kind == "f" else np.iinfo(values.dtype).max
    elif kind == 3:
        values[:] = values[rng.permutation(len(values))]  # unsorted
    elif kind == 4:
        values[rows] = values[rows[0]]  # duplicated
    else:
        columns[name] = values.astype(str)  # wrong type
    pq.write_table(pa.table(columns), path)
    return f"points.parquet {name} mutation {kind}"


def _mutate_recording(folder: Path, rng: np.random.Generator) -> str:
    target = rng.integers(10)
    if target < 5:
        name = TEXT_FILES[target % len(TEXT_FILES)]
        (folder / name).write_bytes(_text_mutation((folder / name).read_bytes(), rng))
        return f"{name} text"
    if target == 5:
        return _points_mutation(folder / "points.parquet", rng)
    if target == 6:
        (folder / "points.parquet").write_bytes(_bytes_mutation((folder / "points.parquet").read_bytes(), rng))
        return "points.parquet bytes"
    name = str(rng.choice(TEXT_FILES + ("points.parquet",)))
    if target == 7:
        (folder / name).unlink()
        return f"{name} missing"
    if target == 8:
        (folder / name).unlink()
        (folder / name).mkdir()
        return f"{name} a directory"
    return f"{name} hostile folder name"


@pytest.fixture
def command_built_once(monkeypatch):
    """typer's runner builds the command tree at every call (half the time of 650 calls): build it once."""
    command = typer.main.get_command(app)
    monkeypatch.setattr(typer.testing, "_get_command", lambda _: command)


def _exit_code(args: list[str]) -> tuple[int, str]:
    result = CliRunner().invoke(app, args)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"graphcal {' '.join(args)} raised {result.exception!r}") from result.exception
    return result.exit_code, result.output


def test_mutated_recordings_are_refused_or_read_never_a_traceback(base, tmp_path, command_built_once):
    from graphcal.calibration.returns import prepare

    rng = np.random.default_rng(20261125)
    outcome = collections.Counter()
    for case in range(RECORDING_CASES):
        folder = tmp_path / f"case{case}"
        shutil.copytree(base[0], folder)
        what = _mutate_recording(folder, rng)
        if what.endswith("hostile folder name"):
            hostile = tmp_path / f"../{case}-x y;$(rm)-\u00e9" / "rec"
            shutil.move(folder, hostile)
            folder = hostile
        code, output = _exit_code(["info", str(folder)])
        assert code in (0, 2), (what, output)
        if code == 2:
            assert output.count("\n") <= 2 and "error:" in output, (what, output)
        else:  # accepted: a calibration's reader must read it too
            try:
                prepare(graphcal.Recording.load(folder), 1.0, 2000)
            except GraphcalError:
                outcome["accepted by info, refused by the calibration's reader"] += 1
        outcome[f"{what.split()[0]}: {'refused' if code == 2 else 'read'}"] += 1
        shutil.rmtree(folder)
    print(dict(sorted(outcome.items())))
    assert sum(v for k, v in outcome.items() if ":" in k) == RECORDING_CASES
    assert outcome["accepted by info, refused by the calibration's reader"] == 0


def test_mutated_calibrations_are_refused_or_applied_at_finite_points(base, tmp_path):
    from graphcal.calibration.evaluate import returns_for, world_of
    from graphcal.calibration.result import Calibration

    recording = graphcal.Recording.load(base[0])
    data = returns_for(Calibration.load(base[1], recording.sensor), recording, max_points=2000)
    rng = np.random.default_rng(7)
    outcome = collections.Counter()
    original = base[1].read_bytes()
    for case in range(MIN_CASES - RECORDING_CASES):
        path = tmp_path / f"calibration{case}.yaml"
        path.write_bytes(_text_mutation(original, rng))
        try:
            calibration = Calibration.load(path, recording.sensor)
        except GraphcalError as error:
            assert str(path) in str(error) or path.name in str(error), error
            outcome["refused"] += 1
            continue
        assert np.all(np.isfinite(world_of(calibration, data))), path.read_text()
        outcome["applied"] += 1
    print(dict(outcome))
    assert outcome["refused"] + outcome["applied"] == MIN_CASES - RECORDING_CASES and outcome["refused"] > 0


IMPORT_CASES = 30  # per importer (pcap, pcd, ouster and las when the real samples are there)


def _import_inputs(root: Path) -> dict[str, tuple[list[str], list[Path]]]:
    """Small valid inputs of every importer: {importer: (its command line up to --out, the files to mutate)}."""
    from ring_scans_synth import kitti_poses, scans, sensor
    from test_importers_cli import _capture_with_fix
    from test_importers_pcd import _scan_array, write_pcd

    root.mkdir()
    inputs = {"pcap": (["import", "pcap", str(_capture_with_fix(root))], [root / "drive.pcap"])}
    folder = root / "pcd"
    folder.mkdir()
    drawn = scans(sensor(with_offsets=False), n_scans=2, columns=40)
    for scan, encoding in zip(drawn, ("ascii", "binary_compressed")):
        write_pcd(folder / f"{round(scan['stamp'] * 1e9)}.pcd", _scan_array(scan, "t", relative=True), encoding)
    poses = root / "poses.txt"
    poses.write_text("".join(" ".join(f"{v:.9f}" for v in p.ravel()) + "\n" for p in kitti_poses(len(drawn))))
    inputs["pcd"] = (["import", "pcd", str(folder), "--poses", str(poses)], sorted(folder.iterdir()) + [poses])
    real = Path(__file__).resolve().parents[2] / "shared/data/real"
    ouster = real / "ouster_sdk_pcaps/OS-0-128-U1_v2.3.0_1024x10"
    if Path(f"{ouster}.pcap").is_file():
        (root / "os0.pcap").write_bytes(Path(f"{ouster}.pcap").read_bytes()[:150_000])  # a few hundred columns
        shutil.copy(f"{ouster}.json", root / "os0.json")
        inputs["ouster"] = (["import", "ouster", str(root / "os0.pcap"), "--metadata", str(root / "os0.json"),
                             "--position", "45,6,300"], [root / "os0.pcap", root / "os0.json"])
    leeward = real / "leeward_airborne_las_sbet"
    if leeward.is_dir():
        for name in ("points.las", "sbet.out"):
            shutil.copy(leeward / name, root / name)
        inputs["las"] = (["import", "las", str(root / "points.las"), "--trajectory", str(root / "sbet.out")],
                         [root / "points.las", root / "sbet.out"])
    return inputs


def test_mutated_import_inputs_are_refused_or_imported_into_a_valid_recording(tmp_path, command_built_once):
    """Every importer on its own small input with one file mutated (bit flips, truncation, empty, garbage, or in a
    text file hostile numbers and lines): a clean refusal that leaves nothing, or a recording that `graphcal info`
    then accepts."""
    outcome = collections.Counter()
    rng = np.random.default_rng(11)
    for importer, (command, files) in _import_inputs(tmp_path / "inputs").items():
        for case in range(IMPORT_CASES):
            originals = {path: path.read_bytes() for path in files}
            target = files[rng.integers(len(files))]
            text = target.suffix in (".txt", ".json") or originals[target][:2] == b"# "
            target.write_bytes((_text_mutation if text else _bytes_mutation)(originals[target], rng))
            out = tmp_path / f"{importer}{case}"
            code, output = _exit_code(command + ["--out", str(out), "-q"])
            assert code in (0, 2), (importer, target.name, output)
            assert code == 0 or not out.exists(), (importer, target.name, "a refused import left", out)
            if code == 0:
                info = _exit_code(["info", str(out), "-q"])
                assert info[0] == 0, (importer, target.name, info[1])
                shutil.rmtree(out)
            outcome[f"{importer}: {'refused' if code == 2 else 'imported'}"] += 1
            for path, data in originals.items():
                path.write_bytes(data)
    print(dict(sorted(outcome.items())))
    assert sum(outcome.values()) >= 2 * IMPORT_CASES
