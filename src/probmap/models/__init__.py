"""probmap.models."""
