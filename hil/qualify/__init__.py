"""Qualifying the acceptance suite by the firmware defects it catches (``hil qualify``).

``defects`` is the catalogue of seeded defects of the built-in controller; ``run`` runs the
suite against each and reports which requirements caught it (``docs/qualify.md``).
"""
