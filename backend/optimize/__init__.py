"""Geometry reconstruction by differentiable path tracing: targets, Laplacian-preconditioned
vertex steps, the constant material model, the coarse-to-fine schedule and the run loop."""
