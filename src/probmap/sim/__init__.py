"""probmap.sim: seeded simulated worlds with ground truth (floor plans, lasers, labels, corridors,
landmarks)."""
