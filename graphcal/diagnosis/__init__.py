"""The mismatch finder: where the model and a recording disagree, which left-out physics explains
it, and the fit with it modelled (graphcal.diagnose)."""
