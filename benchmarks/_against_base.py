"""Shared by the run-time benchmarks: run a command on this checkout and on a base revision (a git
worktree of it, made once), in the same run, and print each figure with its ratio.

Wall time depends on what else the machine runs, so each figure also gives the CPU time of the
command and everything it started (``RUSAGE_CHILDREN``) and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the revision the figures of issue 32 were measured on
BASE_REVISION = "2234cd1"


def arguments(doc: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--base", default=BASE_REVISION, help=f"the revision to compare with (default {BASE_REVISION})")
    p.add_argument("--no-base", action="store_true", help="measure this checkout only")
    return p


def base_checkout(revision: str) -> Path:
    """A worktree of ``revision`` beside the system's temporary files (made on first use)."""
    path = Path(tempfile.gettempdir()) / f"hil-bench-base-{revision}"
    if not (path / "pyproject.toml").is_file():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), revision], check=True,
                       capture_output=True)
    return path


def timed(cmd: list[str], cwd: Path, **kwargs) -> dict:
    """Run ``cmd`` in ``cwd`` with that checkout first on the path: wall and CPU seconds, exit status."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(cwd), *filter(None, [os.environ.get("PYTHONPATH")])])}
    load_before = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, **kwargs)
    wall = time.monotonic() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "returncode": proc.returncode, "stdout": proc.stdout,
            "stderr": proc.stderr, "load": (load_before, os.getloadavg()[0])}


def compare(figure: str, cmd: list[str], args, **kwargs) -> tuple[dict, dict | None]:
    """``cmd`` on this checkout, then on the base revision; prints both and the ratios."""
    head = timed(cmd, ROOT, **kwargs)
    print(line(f"{figure} (this checkout)", head), flush=True)
    base = None
    if not args.no_base:
        base = timed(cmd, base_checkout(args.base), **kwargs)
        print(line(f"{figure} ({args.base})", base), flush=True)
        print(f"{figure}: {head['wall_s'] / base['wall_s']:.2f} x the wall time, "
              f"{head['cpu_s'] / base['cpu_s']:.2f} x the CPU time of {args.base}")
    return head, base


def line(what: str, r: dict) -> str:
    return (f"{what}: {r['wall_s']:.0f} s wall, {r['cpu_s']:.0f} s CPU, exit {r['returncode']}, "
            f"load {r['load'][0]:.1f} -> {r['load'][1]:.1f} on {os.cpu_count()} cores")


PYTHON = sys.executable
