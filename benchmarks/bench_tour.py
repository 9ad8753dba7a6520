"""Wall and CPU time of ``mdft tour``: a first run (kernels compiled) and a second (kernels cached).

Both runs are ``python -m orchestration tour`` processes with the default sizes.
The first uses an empty numba cache folder (``NUMBA_CACHE_DIR``), so every
kernel the tour needs is compiled, as on a fresh installation; the second
reuses that folder, as every later run does. Printed: the wall time of each
step (from the tour's own step lines), the wall time of the process, its CPU
time (user + system, which depends little on what else runs), and the load
average: on a shared machine the wall times are pessimistic.

Target (2-core machine, quiet): about a minute for the first run, compilation
included; well under that for later runs.

Run: ``python benchmarks/bench_tour.py [--quick] [--out DIR]``
"""

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path

from _timing import timed_run

ROOT = Path(__file__).resolve().parents[1]


def run(label, out, cache, quick):
    env = dict(os.environ, MPLBACKEND="Agg", NUMBA_CACHE_DIR=str(cache))
    cmd = [sys.executable, "-m", "orchestration", "tour", "--out", str(out), "--seed", "0"]
    cmd += ["--quick"] if quick else []
    proc, wall, cpu = timed_run(cmd, cwd=ROOT, env=env, label=label)
    steps = re.findall(r"^\[\d+/\d+\] (.*) \.\.\.\n\s+done in ([\d.]+) s", proc.stderr, re.M)
    print(f"{label}: wall {wall:.1f} s, CPU {cpu:.1f} s, 1-min load average after "
          f"{os.getloadavg()[0]:.1f}")
    for step, seconds in steps:
        print(f"    {float(seconds):7.1f} s  {step}")
    return wall, cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    base = Path(args.out or tempfile.mkdtemp(prefix="bench_tour_"))
    cache = base / "numba-cache"
    cache.mkdir(parents=True, exist_ok=True)
    print(f"load average before: {os.getloadavg()}, output in {base}")
    run("first run (compiles)", base / "first", cache, args.quick)
    run("second run (cached)", base / "second", cache, args.quick)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
