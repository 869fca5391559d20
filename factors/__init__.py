"""graphcal's numeric core: sensor model and GTSAM factors as pure functions (no I/O)."""
