"""Mitsuba scene construction and rendering of captures (forward and differentiable)."""
