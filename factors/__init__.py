"""Residual math of gtvo as GTSAM factors with analytic Jacobians.

This package holds the residuals and their Jacobians and nothing else: no file I/O, no
pipeline state. Every factor works in a plain ``gtsam.NonlinearFactorGraph``.
"""
