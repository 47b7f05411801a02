"""Imitation learning on WireCraft datasets: thin wrappers over LeRobot's own training."""
