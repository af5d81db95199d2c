"""The constant material model moved to backend.material.constant; kept importable here."""

from ..material.base import CHANNELS  # noqa: F401
from ..material.constant import START, ConstantMaterial, parse_spec  # noqa: F401
