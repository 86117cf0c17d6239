"""What more than one stage needs and no stage owns: SE(2) geometry, scan geometry, the
odometry buffer. Stages import from here, never from each other or from the CLI."""
