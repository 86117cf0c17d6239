"""laser_legs: person candidates (legs) from every laser scan (DESIGN.md "Leg candidates").

``core`` holds the pure vectorised helpers, ``detectors`` the swappable detectors (``thesis``
by default), ``realdata`` and ``evaluate`` the evaluation on the leg_tracker bags.
"""

from .detectors import DETECTORS, make_detector

__all__ = ["DETECTORS", "make_detector"]
