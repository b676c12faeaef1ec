"""probmap.metrics."""
