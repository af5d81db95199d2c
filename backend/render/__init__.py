"""Mitsuba scene construction and rendering of captures (forward and differentiable).

The package's modules register Mitsuba plugins (the surface BSDF, the projective
integrators) and read the variant's types when imported, so a variant must be set first:
``python -m backend`` sets it for the commands that render, ``tests/conftest.py`` for the
tests, anything else calls :func:`backend.variant.choose` before importing ``backend.render``."""

from ..variant import require

require(__name__)
