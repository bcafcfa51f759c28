"""The fault record: writer, reader, context manifest, per-cycle index for long histories."""
