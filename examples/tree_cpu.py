"""CPU seconds of a command and of every process it starts (a batch's worker processes, which
``/usr/bin/time`` does not count when they are not reaped by the command itself).

    python examples/tree_cpu.py creference batch four_frames/ --out b/ --workers 1

Polls the process tree every 0.1 s and adds each process's last user + system seconds; prints
``cpu_s wall_s`` on standard error when the command ends. A process that lives less than 0.1 s may
be missed (the interpreter's start, a few tenths of a second, is counted for every worker seen).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import psutil


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("command", nargs=argparse.REMAINDER, help="the command and its arguments")
    args = p.parse_args(argv)
    if not args.command:
        p.error("give a command to run")
    start = time.perf_counter()
    proc = subprocess.Popen(args.command)
    root = psutil.Process(proc.pid)
    seen: dict[int, float] = {}
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
        except psutil.NoSuchProcess:
            tree = []
        for p in tree:
            try:
                t = p.cpu_times()
                seen[p.pid] = t.user + t.system
            except psutil.NoSuchProcess:
                pass
        time.sleep(0.1)
    print(f"{sum(seen.values()):.1f} {time.perf_counter() - start:.1f}", file=sys.stderr)
    return proc.returncode


if __name__ == "__main__":
    raise SystemExit(main())
