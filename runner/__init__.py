"""runner: a scenario matrix runner for Linux scheduling ("does my scheduling setup actually work?")."""

__version__ = "0.1.0"
