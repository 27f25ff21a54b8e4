"""Thermal error models: one module per family behind the SensorModel interface (models.base).

Importing this package registers every family, so ``model_from_dict`` can rebuild any of them.
"""

from .base import MODEL_KINDS, model_from_dict, Param, SensorModel  # noqa: F401
from . import polynomial  # noqa: F401  (registers offset_polynomial)
from . import field  # noqa: F401  (registers field_polynomial, seed 000)
from . import rvm  # noqa: F401  (registers rvm, seed 003)
from . import whole_unit  # noqa: F401  (registers the seed 002 whole-unit families)
from . import hysteresis  # noqa: F401  (registers hysteresis_offset: history terms)
