"""Reading a run's .rrd back with rerun's own reader (shared by the run-folder tests)."""

from rerun.chunk import RrdReader


def chunks(path) -> dict:
    """{entity path: [record batches]} of the first recording in an .rrd."""
    found = {}
    for chunk in RrdReader(path).stream().to_chunks():
        found.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return found


def column(batches, name) -> list:
    """The values of one column over the batches that have it."""
    return [value for batch in batches if name in batch.schema.names for value in batch.column(name).to_pylist()]
