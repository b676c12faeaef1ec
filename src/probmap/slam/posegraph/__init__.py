"""Pose-graph optimization: sparse Levenberg-Marquardt on SE(2) with robust kernels and LAGO
initialization (:mod:`~probmap.slam.posegraph.optimize`). File formats live in
:mod:`probmap.datasets.g2o`."""
