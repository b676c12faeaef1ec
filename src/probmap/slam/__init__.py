"""probmap.slam."""
