"""report.html of a diagnosis run folder: the findings, each discovered effect's curve over the binned
residuals before and after it was added, the candidates' first-round tests. Built from diagnosis.json
alone (RECORDING.md "Discovered effects"), one self-contained file (figures as base64 PNG)."""

from __future__ import annotations

import html
import json
from pathlib import Path

from graphcal.common.errors import RecordingError
from graphcal.report import figures
from graphcal.report.html import image, section, table, write_page

DIAGNOSIS_FILE = "diagnosis.json"


def write_diagnosis_report(folder: Path, named_as: Path | None = None) -> Path:
    """Write folder/report.html from the run folder's diagnosis.json; returns its path. named_as: the folder the
    page names (html.write_report)."""
    folder = Path(folder)
    named_as = folder if named_as is None else Path(named_as)
    path = folder / DIAGNOSIS_FILE
    if not path.is_file():
        raise RecordingError(folder, "no diagnosis.json", expected="a diagnosis run folder (graphcal diagnose)")
    diagnosis = json.loads(path.read_text(encoding="utf-8"))
    sections = [_header(named_as, diagnosis), _findings(diagnosis), *map(_discovered, _discovered_findings(diagnosis)),
                _candidates(diagnosis)]
    return write_page(folder, "graphcal diagnosis", sections, named_as)


def _discovered_findings(diagnosis: dict) -> list[dict]:
    return [f for f in diagnosis["findings"] if f["effect"] == "discovered"]


def _number(value, digits: int = 4) -> str:
    return "–" if value is None else f"{value:.{digits}g}"


def _header(folder: Path, diagnosis: dict) -> str:
    energy = diagnosis.get("energy_cm2", {})
    rows = [["run folder", str(folder)], ["seconds", _number(diagnosis.get("seconds"))],
            ["J before → after [cm²]", f"{_number(energy.get('before'))} → {_number(energy.get('after'))}"],
            ["findings", str(len(diagnosis["findings"]))]]
    return f"<h1>graphcal diagnosis report: {html.escape(folder.name)}</h1>" + table(["", ""], rows)


def _findings(diagnosis: dict) -> str:
    statements = [f["statement"] for f in diagnosis["findings"]] + [w["statement"] for w in diagnosis["withdrawn"]]
    statements += [f"not separable: {', '.join(n['effects'])} (correlation {n['correlation']:.2f}, named "
                   f"{n['named']}): {n['would_separate']}" for n in diagnosis["not_separable"]]
    body = "".join(f"<li>{html.escape(s)}</li>" for s in statements) or "<li>no left-out effect is significant</li>"
    return section("Findings", f"<ul>{body}</ul>", "Strongest first; each was added to the model and everything "
                   "re-solved before the next was looked for.")


def _discovered(finding: dict) -> str:
    png = figures.discovered_png(finding["channel"], finding["regressor"], finding["unit"], finding["curve"],
                                 finding["binned_residual_cm"])
    hypotheses = "".join(f"<li>{html.escape(h)}</li>" for h in finding["hypotheses"])
    energy = finding["energy_cm2"]
    return section(f"Discovered: {finding['channel']} against {finding['regressor']}",
                   image(png, f"{finding['channel']} against {finding['regressor']}")
                   + f"<p>Physics that produce this signature, most likely first:</p><ol>{hypotheses}</ol>",
                   f"Left: the fitted curve (constant removed) with its 1σ band. Right: the point-to-plane residuals "
                   f"binned against the {finding['regressor']} before and after the curve was modelled. Held-out J "
                   f"{_number(energy['held_out_before'])} → {_number(energy['held_out_after'])} cm².")


def _candidates(diagnosis: dict) -> str:
    rows = [[c["effect"], _number(c["magnitude"]), _number(c["sigma"]), c["unit"], _number(c["p_value"], 2),
             f"{_number(c['held_out_cm2'][0])} → {_number(c['held_out_cm2'][1])}", _number(c.get("held_out_se_cm2"), 2),
             "yes" if c["significant"] else "no"] for c in diagnosis["candidates"]]
    return section("Every candidate's first-round test", table(
        ["candidate", "size", "σ", "unit", "p", "held-out J [cm²]", "its s.e.", "significant"], rows),
        "Score test at the baseline fit, cluster-robust; significant: below the multiplicity-corrected level, a "
        "positive BIC gain, a held-out J drop larger than its standard error across held-out time blocks, and a "
        "size that moves the cloud by a fraction of the noise worth naming.")
