"""``python -m followbot.services.vision_verify`` (same as ``followbot run vision_verify``)."""

from .node import main

raise SystemExit(main())
