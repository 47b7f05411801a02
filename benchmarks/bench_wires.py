"""Wire-model throughput on one core: ``python benchmarks/bench_wires.py [--seconds 5]``.

The same as ``wirecraft bench --suite wires``; the code lives in wirecraft.bench.wires.
"""

import sys

from wirecraft.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "--suite", "wires", *sys.argv[1:]]))
