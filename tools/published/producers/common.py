"""What the producers share: running a command as a user types it (recorded in the run), the shipped
real captures, and the input globs a group declares.

This file is producer code: it is among every group's inputs (:func:`inputs`), as the producers'
own files are, since a change to how a command is run or a result is read can change any figure.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

from ..model import ROOT, Run

REAL_CAPTURES = ROOT / "tests" / "data" / "real-hall"
#: the shipped real captures as docs/real-captures.md names them
CAPTURE_LABELS = {"20260618-spindle-hw": "spindle", "20250616-hboard-cycle": "hoverboard, speed cycles",
                  "20250616-back-and-forth": "hoverboard, back and forth", "20250615-new-slow": "slow rotation"}
SPINDLE, HOVERBOARD = "20260618-spindle-hw.vcd", "20250616-hboard-cycle.vcd"


def run_hil(run: Run, work: Path, *args: str, timeout_s: float = 3600) -> subprocess.CompletedProcess:
    """``python -m hil ARGS`` from the repository root, recorded in the run's commands."""
    cmd = [sys.executable, "-m", "hil", *args]
    shown = "python -m hil " + " ".join(
        shlex.quote(str(a)).replace(str(work), "$WORK").replace(str(ROOT) + "/", "") for a in args
    )
    run.commands.append(shown)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s)
    run.last_command_s = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{shown} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return done


def with_checkout_on_path() -> dict[str, str]:
    """The environment for a script of this checkout: a script's own directory comes first on its
    path, not the checkout's: without ROOT on PYTHONPATH it would import an installed copy of hil
    (an editable install of another checkout)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


def run_tool(run: Run, script: str, *args: str, timeout_s: float = 3600) -> subprocess.CompletedProcess:
    """``python tools/SCRIPT ARGS`` from the repository root, recorded in the run's commands (the
    scratch directory shown as $WORK)."""
    run.commands.append(re.sub(r"\S*/hil-figures-[^/\s]+", "$WORK",
                               " ".join(["python", f"tools/{script}", *map(shlex.quote, args)])))
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, str(ROOT / "tools" / script), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout_s, env=with_checkout_on_path())
    run.last_command_s = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"tools/{script} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return done


def import_capture(run: Run, work: Path, vcd: str) -> Path:
    """A shipped capture as a recording under ``work`` (imported once per run of the tool)."""
    out = work / Path(vcd).stem
    if not out.exists():
        run_hil(run, work, "recording", "import", str(REAL_CAPTURES / vcd), "-o", str(out))
    return out


def find(tree, key: str):
    """The first value under ``key`` anywhere in a JSON tree (the calibration's keys are unique)."""
    if isinstance(tree, dict):
        if key in tree:
            return tree[key]
        for v in tree.values():
            found = find(v, key)
            if found is not None:
                return found
    elif isinstance(tree, list):
        for v in tree:
            found = find(v, key)
            if found is not None:
                return found
    return None


# ---------------------------------------------------------------- what a group reads
#: what ``python -m hil`` runs, and what any script importing ``hil`` may reach. Not narrower: every
#: command goes through hil/cli.py, which imports each command's modules inside its function, and the
#: imports of the files it reaches (anywhere in a file: tests/test_figures.py follows them) reach all
#: but a handful of the three packages' modules; their data (report templates, device profiles, the
#: firmware-in-the-loop header) are read by the same code.
HIL = ("hil/**", "bldc/**", "plant_models/**")
#: the acceptance suite as ``hil acceptance`` and ``hil qualify`` run it: pytest on test_cases/ from the
#: repository's root, so the root conftest.py and pyproject.toml's pytest settings apply
SUITE = (*HIL, "test_cases/**", "conftest.py", "pyproject.toml")
#: the reference firmware, built and run through ``sil:firmware/reference``
FIRMWARE = ("firmware/reference/**",)


def capture(vcd: str) -> str:
    """A shipped capture's path as a group's inputs name it."""
    return str((REAL_CAPTURES / vcd).relative_to(ROOT))


ALL_CAPTURES = capture("*.vcd")


def inputs(producer: str, *globs: str) -> tuple[str, ...]:
    """A group's inputs: ``globs`` (what its commands run and read), then the code that produces its
    figures: the producer's own module (``producer``: its ``__file__``) and this one."""
    return (*globs, *(str(Path(f).resolve().relative_to(ROOT)) for f in (producer, __file__)))
