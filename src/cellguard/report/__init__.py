"""The HTML incident report: one self-contained page a technician can read offline."""

from cellguard.report.html import render_report

__all__ = ["render_report"]
