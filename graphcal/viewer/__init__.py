"""What graphcal shows in the rerun viewer: a stream that writes run.rrd (and feeds a live viewer
with --spawn), log_* functions per kind of result, and the blueprints that lay them out.
Entity paths and how a new command plugs in: docs/howto/read-the-report-and-viewer.md."""
