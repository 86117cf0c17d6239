"""tracker: every person in the laser with a stable id, one of them the target (issue 6).

``core`` holds the tracker (ego-motion, association, late vision, status), ``estimators`` the
swappable per-person estimators (``particle`` by default, ``ukf``), ``node`` the Zenoh adapter,
``bench`` the particle-filter timing curve.
"""
