"""Wall time of ``mdft reproduce`` for each experiment at the paper's sizes (or ``--quick``).

Each experiment runs as its own ``python -m orchestration reproduce NAME`` process
in a fresh output folder (nothing to resume), with ``--workers`` local processes;
the sum of the times is what ``mdft reproduce all`` takes. Also printed: the CPU
time of the process and its workers (user + system), which depends little on
what else runs on the machine, and the load average before and after: on a
shared machine the wall times are pessimistic.

Targets (2-core machine): ``orchestrators`` at most 5 minutes, ``all`` at most 20.

Run: ``python benchmarks/bench_reproduce.py [--quick] [--workers 2] [--out DIR] [NAME ...]``
(the figures and results stay in ``--out``, by default a temporary folder).
"""

import argparse
import os
import sys
import tempfile
from pathlib import Path

from _timing import timed_run

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["orchestrators", "mdft-vs-wa", "hard-constraints", "soft-constraints", "transfer"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=NAMES)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="bench_reproduce_"))
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    print(f"load average before: {os.getloadavg()}, output in {out}")
    rows = []
    for name in args.names:
        cmd = [sys.executable, "-m", "orchestration", "reproduce", name, "--out", str(out / name),
               "--workers", str(args.workers), "--quiet"] + (["--quick"] if args.quick else [])
        proc, wall, cpu = timed_run(cmd, cwd=ROOT, env=env, label=name)
        rows.append((name, wall, cpu, os.getloadavg()[0]))
        print(f"{name:18s} wall {wall:8.1f} s   CPU {cpu:8.1f} s   "
              f"(1-min load average after: {rows[-1][3]:.1f})", flush=True)
    print(f"{'total (all)':18s} wall {sum(r[1] for r in rows):8.1f} s   "
          f"CPU {sum(r[2] for r in rows):8.1f} s")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
