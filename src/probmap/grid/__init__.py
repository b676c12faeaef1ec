"""probmap.grid."""
