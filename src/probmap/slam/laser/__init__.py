"""Laser SLAM: scan matching, submaps, loop-closure search and verification, submap graph SLAM
(:mod:`~probmap.slam.laser.submap_slam`) and the Rao-Blackwellized particle filter
(:mod:`~probmap.slam.laser.rbpf`)."""
