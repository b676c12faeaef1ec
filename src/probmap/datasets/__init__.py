"""probmap.datasets."""
