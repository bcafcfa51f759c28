"""Guard layer benchmark: cellguard vs a low-pass filter vs a relative clamp on the arm cell (JSON).

The same figures as ``cellguard bench --only guard --json``; see ``cellguard.bench.guard``.
"""

import argparse
import json

from cellguard.bench.guard import figures

if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()  # --help; no options
    print(json.dumps(figures(), indent=1))
