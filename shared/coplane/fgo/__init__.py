"""Sliding-window factor-graph cooperative positioning (paper Section IV) on GTSAM."""
