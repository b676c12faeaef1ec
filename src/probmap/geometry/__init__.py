"""probmap.geometry."""
