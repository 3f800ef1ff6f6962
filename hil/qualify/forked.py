"""The pytest sessions of ``hil qualify``, each forked from one warm process.

Every run of ``hil qualify`` (the control, each defect) is a pytest session in a process of its own:
a defect's controller or firmware never shares state with the next run. Started as
``python -m pytest``, each run paid the interpreter's start and the same imports again (NumPy,
SciPy, numba and the plant's compiled code from its cache, python-can with asammdf, canopen,
pytest and the plugin): about six seconds a run on the 2-core reference machine, forty-odd runs.
Here the runs are forked from one process that has done that once: multiprocessing's
``forkserver`` start method, started on the first run with ``PRELOAD`` imported (its
``hil.preloaded`` loads the numba code), and each child runs ``pytest.main`` with the run's
arguments, environment and working directory, its output to a file, and ends with pytest's exit
code. A run past its time limit is killed, as a ``subprocess`` timeout killed it before.

Where the forkserver start method does not exist (Windows), runs start as ``python -m pytest`` as
before (``FORKED`` is False).
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: what the warm process imports once, for every run forked from it (an ImportError skips a module)
PRELOAD = ("numpy", "numpy.fft", "scipy.linalg", "scipy.optimize", "scipy.signal", "scipy.stats", "numba", "can",
           "canopen", "pymodbus", "hypothesis", "pytest", "hil.pytest_plugin", "hil.dut.spec", "hil.verdicts.report",
           "hil.controller.virtual", "plant_models.simulation", "hil.preloaded")
FORKED = "forkserver" in multiprocessing.get_all_start_methods()
_context = None


def _forkserver():
    global _context
    if _context is None:
        _context = multiprocessing.get_context("forkserver")
        _context.set_forkserver_preload(list(PRELOAD))
    return _context


def _pytest_child(args: list[str], output: str, env: dict[str, str], cwd: str) -> None:
    """In the forked child: the run's environment and directory, its output to ``output``,
    ``pytest.main(args)``, and its exit code as the process's."""
    os.environ.clear()
    os.environ.update(env)
    os.chdir(cwd)
    fd = os.open(output, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    code = 3  # pytest's "internal error", if pytest itself raised
    try:
        import pytest

        code = int(pytest.main(list(args)))
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def run_pytest(args: list[str], timeout_s: float, env: dict[str, str] | None = None,
               cwd: str | os.PathLike | None = None) -> tuple[int | None, str]:
    """One pytest session with ``args`` in ``cwd`` (default: this process's directory): (its exit code,
    its output), the exit code None when it ran past ``timeout_s`` and was killed."""
    env = dict(os.environ if env is None else env)
    cwd = os.fspath(cwd) if cwd is not None else os.getcwd()
    if not FORKED:
        try:
            proc = subprocess.run([sys.executable, "-m", "pytest", *args], capture_output=True, text=True,
                                  timeout=timeout_s, env=env, cwd=cwd)
        except subprocess.TimeoutExpired:
            return None, ""
        return proc.returncode, proc.stdout + proc.stderr
    fd, output = tempfile.mkstemp(prefix="hil-qualify-run-", suffix=".txt")
    os.close(fd)
    try:
        child = _forkserver().Process(target=_pytest_child, args=(list(args), output, env, cwd))
        child.start()
        child.join(timeout_s)
        if child.is_alive():
            child.kill()
            child.join()
            return None, ""
        return child.exitcode, Path(output).read_text(errors="replace")
    finally:
        os.unlink(output)
