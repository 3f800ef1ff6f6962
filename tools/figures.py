"""Every figure published in README.md and docs/, computed from the code at HEAD: ``python
tools/figures.py --help``. The tool is the package beside this script, ``tools/published/``:

- ``engine.py``: the figures file (docs/figures.json), digests and provenance, ``--check``,
  ``--stale``, ``--render``, ``--unmarked`` and its ledger, the inputs' globs, the CI rotation and
  this command line (its docstring has the markers' format and what ``--check`` holds);
- ``model.py``: what a group is (``Group``) and what its producer returns (``Run``, ``Figure``);
- ``producers/``: one module per producer, each declaring its groups with their inputs beside its
  code; ``producers/__init__.py`` lists them in order.
"""

import sys

from published.engine import main

if __name__ == "__main__":
    sys.exit(main())
