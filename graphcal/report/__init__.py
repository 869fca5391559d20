"""The HTML report of a run folder (docs/reference/command-line.md): figures (PNG, matplotlib Agg) and tables,
all inside one self-contained report.html."""
