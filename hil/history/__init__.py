"""The results history (docs/history.md): every run remembered in a database.

Every ``hil acceptance``, ``hil qualify`` run, ``hil campaign`` and pytest session that uses the
plugin is recorded, by default in an embedded SQLite file (``default_location``), or wherever
``--history URL`` / ``HIL_HISTORY`` point (``off`` turns it off). A team shares one PostgreSQL
database through the same URL form (``postgresql+psycopg://user@host/db``).

* ``hil.history.record``: what a record holds, built from a report's content (pure Python);
* ``hil.history.store``: the schema (SQLAlchemy Core), its migrations and the queries;
* ``hil.history.compare``: diffs between runs, trends and regressions (pure Python);
* ``hil.history.hook``: what a run calls (never costs it its report: one warning line);
* ``hil.history.cli``: ``hil history list|show|diff|trend|import``.

Nothing here imports SQLAlchemy at module level except ``store``: a pytest session that never
uses the plugin loads none of it (tests/test_plugin_lazy.py).
"""
