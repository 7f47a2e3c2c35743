"""The recording of the data contract: four probe signals and their metadata.

Defined in ``tactile_jax.contract``, which the analysis imports too (it imports nothing of ``io``);
this module keeps the names where the readers and writers, and users, import them.
"""

from __future__ import annotations

from ..contract import CHANNELS as CHANNELS
from ..contract import SENSOR_DEFAULT as SENSOR_DEFAULT
from ..contract import SENSOR_FROM_FILE as SENSOR_FROM_FILE
from ..contract import Recording as Recording
from ..contract import validate_recording as validate_recording

__all__ = ["CHANNELS", "SENSOR_DEFAULT", "SENSOR_FROM_FILE", "Recording", "validate_recording"]
