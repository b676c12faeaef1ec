"""probmap.viz."""
