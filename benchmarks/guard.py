"""Guard layer benchmark: cellguard vs a low-pass filter vs a relative clamp on the arm cell (JSON).

The same figures as ``cellguard bench --only guard --json``; see ``cellguard.bench.guard``.
"""

import json

from cellguard.bench.guard import figures

if __name__ == "__main__":
    print(json.dumps(figures(), indent=1))
