"""Run ``vpsim bench`` and keep its figures: a JSON file named after the date and the machine.

    pip install -e '.[bench]'                  # FASTSim 3.1.0, the peer
    python benchmarks/run_bench.py             # full profile, writes benchmarks/results/<date>-<host>.json
    python benchmarks/run_bench.py --quick     # under a minute

The same as ``vpsim bench --json FILE``; see benchmarks/README.md for what is measured and how to read it.
"""

from __future__ import annotations

import datetime
import platform
import sys
from pathlib import Path

from vpsim.cli.main import main

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--json" not in args:
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = Path(__file__).parent / "results" / f"{stamp}-{platform.node() or 'machine'}.json"
        args += ["--json", str(out)]
    sys.exit(main(["bench", *args]))
