"""Wall and CPU time of a command run in a child process, shared by the benchmark scripts."""

import resource
import subprocess
import sys
import time


def timed_run(cmd, *, cwd, env, label):
    """Run ``cmd``; return ``(proc, wall seconds, CPU seconds of the child)``.

    Exits with the child's stderr when it fails, naming ``label``.
    """
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        sys.exit(f"{label} failed:\n{proc.stderr}")
    return proc, wall, cpu
