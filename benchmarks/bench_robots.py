"""Robot throughput on one core: ``python benchmarks/bench_robots.py [--seconds 3]``.

The same as ``wirecraft bench --suite robots``; the code lives in wirecraft.bench.robots.
"""

import sys

from wirecraft.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", "--suite", "robots", *sys.argv[1:]]))
