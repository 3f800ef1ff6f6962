"""``hil acceptance`` compiles the numba code once, ahead, while pytest starts; the workers wait for
it before their first test (hil/compile_ahead.py). The compile itself is a figure
(docs/acceptance.md, "The first run"), not a test: here the lock and its wiring."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

import hil.compile_ahead as ahead_mod

ROOT = Path(__file__).resolve().parents[1]
fcntl = pytest.importorskip("fcntl")


def _ahead(monkeypatch, body: str) -> ahead_mod.CompileAhead:
    """A CompileAhead whose process runs ``body`` instead of the compile."""
    monkeypatch.delenv(ahead_mod.LOCK_ENV, raising=False)  # this session's own compile ahead
    real_popen = subprocess.Popen
    monkeypatch.setattr(subprocess, "Popen", lambda cmd, **kw: real_popen([sys.executable, "-c", body], **kw))
    monkeypatch.setattr(ahead_mod, "uncompiled_parts", lambda: list(ahead_mod.PARTS))
    return ahead_mod.CompileAhead({**os.environ, "PYTHONPATH": str(ROOT)}).start()


def test_a_waiting_process_passes_only_when_the_compile_is_done(monkeypatch):
    ahead = _ahead(monkeypatch, "import time; time.sleep(1.5)")
    env = {**os.environ, **ahead.env(), "PYTHONPATH": str(ROOT)}
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from hil.compile_ahead import wait_for_compile_ahead as w; w()"],
                   env=env, check=True, cwd=ROOT)
    waited = time.perf_counter() - started
    assert waited >= 1.0, waited  # it waited for the compile
    ahead.close()
    assert not Path(env[ahead_mod.LOCK_ENV]).exists()
    # without the variable, or with its file gone, nothing waits
    monkeypatch.delenv(ahead_mod.LOCK_ENV, raising=False)
    ahead_mod.wait_for_compile_ahead()
    monkeypatch.setenv(ahead_mod.LOCK_ENV, env[ahead_mod.LOCK_ENV])
    ahead_mod.wait_for_compile_ahead()


def test_the_parts_compile_side_by_side_and_the_lock_holds_until_the_last_is_done(monkeypatch):
    """One process per part (the plant kernel, the controller's code: they share no numba function),
    both at once; a waiter passes when the slower has ended."""
    ahead = _ahead(monkeypatch, "import time; time.sleep(1.5)")
    assert len(ahead._procs) == len(ahead_mod.PARTS) == 2
    started = time.perf_counter()
    env = {**os.environ, **ahead.env(), "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-c", "from hil.compile_ahead import wait_for_compile_ahead as w; w()"],
                   env=env, check=True, cwd=ROOT)
    assert 1.0 <= time.perf_counter() - started < 2.9  # side by side, not one after the other
    ahead.close()


def test_a_compile_ahead_inside_another_starts_nothing(monkeypatch):
    """``hil acceptance`` run by the test session, which compiles ahead for itself and the run."""
    outer = _ahead(monkeypatch, "import time; time.sleep(2)")
    inner = ahead_mod.CompileAhead({**os.environ, **outer.env()}).start()
    assert inner._procs == [] and inner.env() == {}
    outer.close()


def test_a_compile_still_running_when_pytest_ends_is_stopped(monkeypatch):
    ahead = _ahead(monkeypatch, "import time; time.sleep(60)")
    started = time.perf_counter()
    ahead.close()
    assert time.perf_counter() - started < 10 and ahead._procs and all(p.poll() is not None for p in ahead._procs)


def test_a_failed_compile_says_so_in_one_line(monkeypatch, capsys):
    def broken(part=None):
        raise RuntimeError("no compiler")

    monkeypatch.setattr(ahead_mod, "compile_numba_code", broken)
    assert ahead_mod.main(["plant"]) == 0
    assert capsys.readouterr().err.strip() == (
        "hil: compiling ahead failed (RuntimeError: no compiler); the workers compile for themselves")


def test_the_mark_says_compiled_until_a_source_changes(tmp_path, monkeypatch):
    pkg = tmp_path / "src" / "toy_numba"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "kernel.py").write_text("x = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path / "src"))
    monkeypatch.setattr(ahead_mod, "NUMBA_PACKAGES", ("toy_numba",))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    assert not ahead_mod.compiled_already()
    ahead_mod._mark_compiled("plant")
    assert ahead_mod.compiled_already("plant") and not ahead_mod.compiled_already()  # a part is not the whole
    ahead_mod._mark_compiled("controller")
    assert ahead_mod.compiled_already()
    ahead = ahead_mod.CompileAhead().start()  # a warm cache: no process, no lock, nobody waits
    assert ahead._procs == [] and ahead.env() == {}
    (pkg / "kernel.py").write_text("x = 22\n")
    assert not ahead_mod.compiled_already()


def test_hil_acceptance_runs_pytest_under_the_lock(monkeypatch, tmp_path):
    from hil import cli

    seen = {}
    ahead = {}
    real_start = ahead_mod.CompileAhead.start

    def start(self):
        ahead["it"] = self
        return real_start(self)

    def fake_run(cmd, env):
        seen["lock"] = env.get(ahead_mod.LOCK_ENV)
        seen["held"] = Path(seen["lock"]).exists()
        return subprocess.CompletedProcess(cmd, 0)

    monkeypatch.delenv(ahead_mod.LOCK_ENV, raising=False)  # this session's own compile ahead
    monkeypatch.setattr(ahead_mod.CompileAhead, "start", start)
    monkeypatch.setattr(ahead_mod, "uncompiled_parts", lambda: list(ahead_mod.PARTS))
    monkeypatch.setattr(subprocess, "run", fake_run)
    cli.main(["acceptance", "-o", str(tmp_path / "rep"), "-j", "0"])
    assert seen["lock"] and seen["held"]
    assert not Path(seen["lock"]).exists()  # removed when pytest ended
    assert all(p.poll() is not None for p in ahead["it"]._procs)  # and the compile stopped, nothing waiting for it
