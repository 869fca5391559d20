"""The command line (`graphcal ...`), the run folders its commands write, and the demo."""
