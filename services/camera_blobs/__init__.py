"""camera_blobs: person candidates from the camera alone, by a learnt clothing colour (seed 001)."""
