"""The numba code of an acceptance run compiled once, ahead, while pytest starts (issue 40, item 5).

On a fresh numba cache every pytest-xdist worker of ``hil acceptance`` compiled the plant kernel,
the controller's filters and the signal extractor itself, at the same time, so the first run paid
the compile once per worker. Now ``hil acceptance`` compiles them once, in processes of their own
(``python -m hil.compile_ahead PART``), while pytest starts, collects and spawns its workers; each
worker waits for that compile before its first test (the plugin's ``pytest_runtestloop``, through
the lock file named by ``HIL_COMPILE_LOCK``) and then loads all of the code from numba's cache
before the first test (no test meets a load while a link's reply is timed). The compile is split
in two parts that share no numba function, side by side on two cores: the plant kernel (about
15 s of CPU alone) and the controller's code (its filters, 14 s, and the signal extractor, 5 s).
Each part leaves a mark beside numba's cache (numba's and Python's versions, the stamp of every
source with numba code); while the marks hold, the cache is warm and nothing is started (a warm
run pays nothing: the check imports neither numba nor the plant). The test session compiles ahead
the same way, once for its workers and the acceptance run it starts (``tests/conftest.py``).

What was measured before deciding (docs/acceptance.md, "The first run"): compiling the plant
kernel without numba's IR inlining halves its compile but slows the plant by a fifth to a
third; the signatures compiled twice are literal specialisations (a branch pruned per call site);
a cache shipped with the package is invalid on another machine (numba keys it to the CPU's name
and features). The plant's numerics are untouched: the same code is compiled.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

#: the environment variable naming the lock file the workers wait on
LOCK_ENV = "HIL_COMPILE_LOCK"
#: the packages whose modules hold numba code (their sources stamp the cache, as numba's own index
#: stamps each cached function with its file's modification time and size)
NUMBA_PACKAGES = ("plant_models", "hil.predictors", "hil.signals", "hil.controller", "bldc")


def _stamp() -> tuple[Path, dict] | None:
    """(where the parts' marks go, what each must say): the numba cache directory (NUMBA_CACHE_DIR,
    else the plant's ``__pycache__``), numba's and Python's versions, the stamp of every source of
    ``NUMBA_PACKAGES``. Found without importing them (no numba, no plant: a warm run pays nothing)."""
    import importlib.metadata
    import importlib.util

    sources = {}
    for package in NUMBA_PACKAGES:
        spec = importlib.util.find_spec(package)
        if spec is None or not spec.submodule_search_locations:
            return None
        for folder in spec.submodule_search_locations:
            for path in sorted(Path(folder).glob("*.py")):
                st = path.stat()
                sources[str(path)] = [st.st_mtime_ns, st.st_size]
    plant = Path(importlib.util.find_spec("plant_models").submodule_search_locations[0])
    cache = Path(os.environ["NUMBA_CACHE_DIR"]) if os.environ.get("NUMBA_CACHE_DIR") else plant / "__pycache__"
    what = {"numba": importlib.metadata.version("numba"), "python": sys.version, "sources": sources}
    return cache, what


def _mark(cache: Path, part: str) -> Path:
    return cache / f"hil-compiled-{part}.json"


def uncompiled_parts() -> list[str]:
    """The parts whose ``compile_numba_code(part)`` has not run to its end against these very
    sources and this cache (the mark it leaves; the sources are stamped once for all parts); a
    cache emptied since only means the workers compile, as they did before."""
    import json

    stamp = _stamp()
    if stamp is None:
        return list(PARTS)
    cache, what = stamp
    todo = []
    for part in PARTS:
        try:
            if json.loads(_mark(cache, part).read_text()) == what:
                continue
        except (OSError, ValueError):
            pass
        todo.append(part)
    return todo


def compiled_already(part: str | None = None) -> bool:
    """Whether ``part`` (every part, for None) is compiled (``uncompiled_parts``)."""
    todo = uncompiled_parts()
    return not todo if part is None else part not in todo


def _mark_compiled(part: str) -> None:
    import json

    stamp = _stamp()
    if stamp is None:
        return
    cache, what = stamp
    try:
        cache.mkdir(parents=True, exist_ok=True)
        _mark(cache, part).write_text(json.dumps(what))
    except OSError:
        pass


#: the compile split in parts that share no numba function, one process each (the machine's two
#: cores): the plant kernel alone takes about 15 s, the controller's filters 14 s, the signal
#: extractor 5 s (docs/acceptance.md, "The first run")
PARTS = ("plant", "controller")


def compile_numba_code(part: str | None = None) -> None:
    """Call each numba function an acceptance run calls, once, on a tiny case; loads from numba's
    cache when it is warm, compiles and writes it when it is cold. ``part``: "plant" (the plant
    kernel, on a lockstep bench whose controller runs no filter), "controller" (the controller's
    filters as a device warms them, and the signal extractor on a tiny six-step capture), or None
    (both)."""
    if part in (None, "plant"):
        from bldc.contract import Strategy
        from plant_models import paper_bench

        from .bench.lockstep import LockstepBench
        from .controller.virtual import VirtualController
        from .dut.in_process import InProcessLink

        config = paper_bench(True)
        controller = VirtualController(config.motor, strategy=Strategy.CORRECTED, speed_setpoint_rpm=5000.0)
        LockstepBench(config, InProcessLink(controller)).sim.run_until(0.05)
    if part in (None, "controller"):
        import numpy as np

        from .controller.virtual import warm_up
        from .signals.commutations import Extractor

        warm_up()
        # any gate states do: numba compiles for the argument types, not the values
        states = np.arange(24, dtype=np.int64) % 64
        extractor = Extractor(resolution_s=1e-6)
        extractor.feed(np.arange(states.size) * 25e-6, states)
        extractor.finish(states.size * 25e-6)


class CompileAhead:
    """``compile_numba_code`` in processes of their own (``python -m hil.compile_ahead PART``, one
    per part not yet compiled, side by side), which together hold an exclusive lock on a file until
    the last is done; ``env()`` names the file for the processes that must wait
    (``wait_for_compile_ahead``). Processes, not threads: nothing is imported into the caller
    (``hil acceptance`` may run inside a test). Started under a compile ahead already (its lock in
    the environment: the test session's, around the acceptance run it starts), it starts nothing."""

    def __init__(self, env: dict[str, str] | None = None):
        self._env = env
        self._path: str | None = None
        self._procs: list = []

    def start(self) -> CompileAhead:
        import subprocess

        try:
            import fcntl
        except ImportError:  # no flock (Windows): the workers compile as they did
            return self
        upstream = (self._env if self._env is not None else os.environ).get(LOCK_ENV)
        if upstream and Path(upstream).exists():  # an enclosing compile ahead: its waiters wait for it
            return self
        parts = uncompiled_parts()
        if not parts:  # a warm cache: nothing to compile, nobody waits
            return self
        fd, path = tempfile.mkstemp(prefix="hil-compile-", suffix=".lock")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # taken before any worker exists: none can pass it early
            # each child inherits the locked file: the lock goes when the last child exits
            for part in parts:
                self._procs.append(subprocess.Popen([sys.executable, "-m", "hil.compile_ahead", part], pass_fds=(fd,),
                                                    env=self._env, stdout=subprocess.DEVNULL))
            self._path = path
        except OSError:
            self.close()
            Path(path).unlink(missing_ok=True)
        finally:
            os.close(fd)
        return self

    def env(self) -> dict[str, str]:
        return {LOCK_ENV: self._path} if self._path else {}

    def close(self) -> None:
        """pytest has ended: remove the lock file; a compile still running (pytest stopped early)
        is stopped, nothing waits for it."""
        for proc in self._procs:
            if proc.poll() is None:
                proc.terminate()
            proc.wait()  # reaped: its CPU time counts among this process's children
        if self._path:
            Path(self._path).unlink(missing_ok=True)


def wait_for_compile_ahead() -> None:
    """Block until the compile ahead (if this process was started under one) is done."""
    path = os.environ.get(LOCK_ENV)
    if not path:
        return
    try:
        import fcntl

        with open(path) as f:
            fcntl.flock(f, fcntl.LOCK_SH)
            fcntl.flock(f, fcntl.LOCK_UN)
    except (ImportError, OSError):  # no lock to wait on: compile here, as before
        return


_loaded = False  #: load_compiled has run in this process


def load_compiled() -> None:
    """In a worker, after the compile ahead: the same calls, now loading every function from the
    cache (a second or two), before any test runs; once per process (the test session's conftest
    and the plugin both ask). A failure here is left to the tests to meet."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    try:
        compile_numba_code()
    except Exception:
        pass


def main(argv: list[str] | None = None) -> int:
    """The process CompileAhead starts, for one part (every part without an argument): compile, and
    mark it compiled; its inherited lock goes when it exits."""
    args = sys.argv[1:] if argv is None else argv
    parts = args[:1] if args else list(PARTS)
    try:
        for part in parts:
            compile_numba_code(part)
            _mark_compiled(part)
    except Exception as exc:  # the workers compile for themselves, as before
        print(f"hil: compiling ahead failed ({type(exc).__name__}: {exc}); the workers compile for themselves",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
