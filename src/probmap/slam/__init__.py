"""SLAM: laser SLAM (:mod:`probmap.slam.laser`), landmark SLAM (:mod:`probmap.slam.landmark`)
and pose-graph optimization (:mod:`probmap.slam.posegraph`)."""
