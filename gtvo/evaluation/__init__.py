"""Trajectories and the metrics that compare them (ATE, RPE, drift, KITTI segments): pure math, no I/O."""
