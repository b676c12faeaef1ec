"""Landmark (feature-based) SLAM: data association, EKF SLAM, SEIF SLAM, FastSLAM and the
GraphSLAM smoother (Probabilistic Robotics ch. 10-13)."""
