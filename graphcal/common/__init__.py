"""What every stage shares: atomic writes, errors, progress bars, numeric CSV tables, YAML files, run folders."""
