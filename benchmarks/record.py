"""Fault record figures: recorder cost per servo tick, MB per hour, read one cycle, 30-day index query.

    .venv/bin/python benchmarks/record.py [--quick]

Prints one JSON document. The same figures appear in ``cellguard bench``.
"""

from __future__ import annotations

import argparse
import json
import sys

from cellguard.bench.record import figures

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter recordings (the 30-day query is unchanged)")
    args = parser.parse_args()
    sys.stdout.write(json.dumps(figures(quick=args.quick), indent=1) + "\n")
