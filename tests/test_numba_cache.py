"""The plant's numba cache follows every source of the package, not only the kernel's own file."""

import json

from plant_models import _numba_cache as cache


def test_a_changed_source_drops_the_cached_index_once(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    (folder,) = cache.cache_dirs()
    folder.mkdir()
    (folder / "_kernel.run-336.py311.nbi").write_bytes(b"index")
    (folder / "_kernel.run-336.py311.1.nbc").write_bytes(b"code")
    stale = {**cache.sources_stamp(), "sensor.py": [1, 2]}  # sensor.py edited since the kernel was cached
    (folder / cache.STAMP_NAME).write_text(json.dumps(stale))
    removed = cache.drop_stale_cache()
    assert [p.name for p in removed] == ["_kernel.run-336.py311.nbi"]
    assert json.loads((folder / cache.STAMP_NAME).read_text()) == cache.sources_stamp()
    (folder / "_kernel.run-336.py311.nbi").write_bytes(b"index, compiled afresh")
    assert cache.drop_stale_cache() == [] and (folder / "_kernel.run-336.py311.nbi").exists()


def test_the_first_process_on_an_empty_cache_directory_stamps_it_so_the_next_keeps_what_it_compiled(
        tmp_path, monkeypatch):
    """A new NUMBA_CACHE_DIR: the stamp goes where numba will write (before, no folder existed to
    stamp, and the second process dropped everything the first had compiled: two cold runs)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert cache.drop_stale_cache() == []
    (folder,) = cache.cache_dirs()
    assert json.loads((folder / cache.STAMP_NAME).read_text()) == cache.sources_stamp()
    (folder / "_kernel.run-336.py311.nbi").write_bytes(b"index")  # numba's first compile
    assert cache.drop_stale_cache() == []


def test_the_folder_is_the_one_numba_writes(tmp_path):
    """Run in a process of its own with NUMBA_CACHE_DIR set: numba's cache of the plant lands in the
    folder the stamp guards."""
    import os
    import subprocess
    import sys

    code = ("from plant_models import _numba_cache as c, _kernel\n"
            "from numba.core.caching import FunctionCache\n"
            "print(FunctionCache(_kernel.run.py_func)._cache_path)\n"
            "print(c.cache_dirs()[0])\n")
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)},
                         capture_output=True, text=True, check=True).stdout.split()
    assert out[0] == out[1]
