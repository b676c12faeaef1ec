"""probmap.filters."""
