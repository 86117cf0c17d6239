"""followbot: a robot follows one chosen person (laser legs + camera + particle filter)."""

__version__ = "0.1.0"
