"""Fitting a capture by differentiable path tracing: ``run.reconstruct`` (the one entry point),
its levels and polish rounds, transitions, appearance, budget, convergence rules, records,
targets and vertex steps. Nothing here imports ``backend.planning``."""
