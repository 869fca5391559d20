"""The HTML report of a run folder (docs/cli.md): figures (PNG, matplotlib Agg) and tables,
all inside one self-contained report.html."""
