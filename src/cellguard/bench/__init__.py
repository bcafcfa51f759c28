"""Benchmarks that drive the whole tick path (they may import the runner); figures only, never asserted."""
