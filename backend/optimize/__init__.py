"""Geometry reconstruction by differentiable path tracing: ``run.reconstruct`` (the library
call), its levels and polish rounds, budget, records, targets, vertex steps and schedule."""
