"""The core layer: camera models, images, SE(3) / quaternion helpers and the compiled-loop decorator.

Imports nothing of gtvo but :mod:`gtvo.errors`, and nothing of :mod:`factors`: every other
layer may build on it (docs/architecture.md, "Layers").
"""
