"""PyBullet cloth simulation, virtual RGB-D camera and ground truth."""
