"""Landmark (feature-based) SLAM: estimators of a robot's path and a map of point landmarks."""
