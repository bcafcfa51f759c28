"""Benchmarks that drive the whole tick path (they may import the runtime); figures only, never asserted."""
