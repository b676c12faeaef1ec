"""probmap.mapping: maps from known poses beyond the per-cell filter: MAP mapping, sonar cones."""
