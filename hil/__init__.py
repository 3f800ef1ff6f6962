"""The HIL framework: pytest plugin, recordings, controller links, bench loop, budgets, reports, gap."""

__version__ = "0.1.0"
