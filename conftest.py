"""Project-level pytest configuration. The HIL fixtures come from the ``hil`` plugin (pytest11)."""

import os

# pytester's in-process runs drop the modules first imported inside them; numpy >= 2.4 and SciPy's
# C extensions refuse a second import in one process ("cannot load module more than once per
# process"), so what the plant and the plugin import is imported here, ahead of every such run
import numpy.fft  # noqa: F401
import scipy.linalg  # noqa: F401
import scipy.optimize  # noqa: F401
import scipy.signal  # noqa: F401
import scipy.stats  # noqa: F401

import pytest

pytest_plugins = ["pytester"]

#: README's test command (``python -m pytest -q``, no paths: the ini's testpaths) runs on this
#: many pytest-xdist workers, one test file each at a time (a file's module fixtures, such as
#: tests/test_browser.py's acceptance run, are made once); ``HIL_TEST_WORKERS=0`` runs it in one
#: process. A run that names paths or gives ``-n`` itself is left alone.
WORKERS_ENV = "HIL_TEST_WORKERS"


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Ahead of xdist's own hook (a conftest's hook of the same order runs first), so xdist sets up
    the workers as if ``-n N --dist loadfile`` had been given."""
    if hasattr(config, "workerinput") or getattr(config.option, "numprocesses", "absent") is not None:
        return None  # an xdist worker, -n given, or xdist disabled (-p no:xdist)
    if config.args_source != pytest.Config.ArgsSource.TESTPATHS:
        return None
    if config.option.collectonly or config.option.usepdb:
        return None
    text = os.environ.get(WORKERS_ENV, "")
    try:
        workers = int(text) if text else min(os.cpu_count() or 1, 4)
    except ValueError:
        raise pytest.UsageError(f"{WORKERS_ENV}={text!r}: give a number of workers (0: none)") from None
    if workers >= 2:
        config.option.numprocesses = workers
        config.option.dist = "loadfile"
    return None
