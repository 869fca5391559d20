"""Benchmark: graphcal.diagnose(recording) as a new user runs it, no option given, on recordings of the
independent simulator (tools/foreign_sim, box_street, tilted mount, 1 cm range noise) of about 4 M and 40 M
returns, and drives of some minutes (--minutes, at --size: beyond the default subset's cap, the diagnosis
reads spans of the drive). The budget: within 5 minutes on 2 cores for 4 M returns, within 15 for 40 M.

Each case in its own process (its own peak memory): the seconds of the whole diagnosis, peak memory, the
findings. Prints the figures and writes benchmarks/results/diagnose_budget.json.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from pathlib import Path

from common import machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools.foreign_sim, from the checkout
FIRINGS_PER_S = 0.62e6  # returns a second of the foreign simulator's HDL-32E at size 1 (measured: 9.97 M in 16 s)


def _case(folder: str, queue) -> None:
    import graphcal

    recording = graphcal.Recording.load(folder)
    started = time.perf_counter()
    diagnosis = graphcal.diagnose(recording, quiet=True)
    queue.put({"returns": len(recording.points), "seconds": round(time.perf_counter() - started, 1),
               "peak_gib": round(peak_gib(), 2),
               "findings": [f["effect"] if f["effect"] != "discovered" else
                            f"discovered {f['channel']} x {f['regressor']}" for f in diagnosis.findings],
               "summary": diagnosis.summary()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--millions", type=float, nargs="*", default=[4.0, 40.0], help="returns of each case [M]")
    parser.add_argument("--minutes", type=float, nargs="*", default=[],
                        help="also drives of these lengths at --size (beyond the default subset's cap: spans)")
    parser.add_argument("--size", type=float, default=0.25, help="fraction of firings of the --minutes drives")
    parser.add_argument("--result", default="diagnose_budget.json", help="file name in benchmarks/results/")
    parser.add_argument("--keep", help="folder where the simulated recordings are kept and found again (default: a "
                                       "temporary folder, simulated each run)")
    args = parser.parse_args()
    from tools.foreign_sim import simulate

    figures = {"machine": {**machine(), "load_average_at_start": round(os.getloadavg()[0], 2)},
               "date": datetime.date.today().isoformat(), "cases": {}}
    cases = {}
    for millions in args.millions:
        duration_s = max(16.0, millions * 1e6 / FIRINGS_PER_S)
        cases[f"{millions:g} M"] = (f"box_street_{millions:g}M", duration_s,
                                    min(1.0, millions * 1e6 / (FIRINGS_PER_S * duration_s)))
    for minutes in args.minutes:
        cases[f"{minutes:g} min"] = (f"box_street_{minutes:g}min_size{args.size:g}", 60.0 * minutes, args.size)
    for case, (name, duration_s, size) in cases.items():
        with tempfile.TemporaryDirectory() as folder:
            recording = Path(args.keep or folder) / name
            if not (recording / "recording.yaml").exists():
                simulate("box_street", recording, duration_s=duration_s, size=size, seed=4, mount="tilted")
            figures["cases"][case] = {"duration_s": round(duration_s, 1), "size": round(size, 3),
                                      **run_in_process(_case, str(recording))}
    RESULTS.mkdir(exist_ok=True)
    report(figures, RESULTS / args.result)


if __name__ == "__main__":
    main()
