"""Cycles, baseline, drift, last-good versus faulted, asymmetry, probable cause."""
