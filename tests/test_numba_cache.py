"""The plant's numba cache follows every source of the package, not only the kernel's own file."""

import json

from plant_models import _numba_cache as cache


def test_a_changed_source_drops_the_cached_index_once(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    folder = tmp_path / "plant_models_0123abcd"
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
