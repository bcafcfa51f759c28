"""Benchmarks: figures printed as JSON by `cellguard bench` and `benchmarks/`; above the runner, never imported by the library."""
