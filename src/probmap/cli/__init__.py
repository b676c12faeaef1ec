"""probmap.cli."""
