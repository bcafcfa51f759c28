"""Executor (chunks -> reference) and envelope (limits, watchdog, stops)."""
