"""Verdicts and their presentation, from the requirement to the page:

- ``requirements`` (the registry: statement, test, doc page, device-profile needs, default
  budgets; ``python -m hil.verdicts.requirements`` rewrites the docs' tables), whose default
  limits ``budget_sources`` derives from their outside sources;
- ``budgets`` (limits, marginal bounds, waivers, and the ``Verdict`` of a figure against them),
  ``judging`` (what a failing acceptance test says of the device);
- ``report`` (verdict rules, JSON, JUnit and HTML), ``report_html`` (the HTML's presentation),
  ``plots`` (figures for the report), ``progress`` (a run's progress line).

Import the module you need; this package imports nothing.
"""
