"""tracker: every person in the laser with a stable id, one of them the target.

``core`` holds the tracker's step, which calls one module per role (``egomotion``,
``lifecycle``, ``association``, ``identity``, ``search``, ``report``; ``settings`` for all of
them); ``estimators`` the swappable per-person estimators (``particle`` by default, ``ukf``),
``node`` the Zenoh adapter, ``bench`` the particle-filter timing curve.
"""
