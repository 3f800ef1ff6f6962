"""Keep numba's on-disk cache of the plant's kernel true to its sources.

numba's cache index stamps a cached function with the modification time and size of its own
file only. The kernel (``_kernel.py``) inlines functions of ``sensor.py`` and ``layout.py``, so an
edit there left the compiled kernel stale and every run used the old code without a word (an edit
to the armature lag did). One stamp of every source of the package is kept beside the cache; when
it differs, the package's index files go, and numba compiles afresh at the first call.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
STAMP_NAME = "plant-sources.json"


def cache_dirs() -> list[Path]:
    """Where numba keeps this package's cache: ``__pycache__`` beside the sources, or under
    ``NUMBA_CACHE_DIR`` in a folder named after the package."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    if root:
        # the folder numba itself names for this very package (another clone's is another folder;
        # it need not exist yet: the stamp goes in before numba's first write, or numba's first
        # cache would be taken for a stale one by the next process and compiled again)
        from numba.core.caching import _CacheLocator

        return [Path(root) / _CacheLocator.get_suitable_cache_subpath(str(PACKAGE_DIR / "_kernel.py"))]
    return [PACKAGE_DIR / "__pycache__"]


def sources_stamp() -> dict[str, list[int]]:
    return {p.name: [p.stat().st_mtime_ns, p.stat().st_size] for p in sorted(PACKAGE_DIR.glob("*.py"))}


def drop_stale_cache() -> list[Path]:
    """Remove the index files of every cache of this package whose stamp is not that of the present
    sources, and stamp it; returns the removed files. Processes that race here remove the same files
    (a missing one is skipped) before any of them compiles: nothing compiled is ever lost but stale code."""
    stamp, removed = sources_stamp(), []
    for folder in cache_dirs():
        mark = folder / STAMP_NAME
        try:
            if json.loads(mark.read_text()) == stamp:
                continue
        except (OSError, ValueError):
            pass
        for index in folder.glob("*.nbi"):
            try:
                index.unlink()
                removed.append(index)
            except FileNotFoundError:
                pass
        try:
            folder.mkdir(parents=True, exist_ok=True)
            mark.write_text(json.dumps(stamp))
        except OSError:  # a read-only install: numba cannot cache there either
            pass
    return removed
