"""tactile_jax: slip velocity, contact radius and texture spectra from a vertical-sampling tactile sensor.

Physics (pure JAX): ``decay``, ``window``, ``r_curve``, ``probe``.
Measurement: ``spectra``, ``prewhiten``. Estimation: ``closed_form``, ``pair_fit`` (one pair alone) and
``joint`` (both pairs: the compiled pipeline of ``fit`` and ``batch``), ``posterior`` (emcee).
Scenes and files: ``scene``, ``texture``, ``recording``, ``io``. Edges: ``plotting``, ``report``, ``cli``, ``demo``.
The library never switches on float64 itself: call
``jax.config.update("jax_enable_x64", True)`` first (the CLI does).
"""

from .model.closed_form import SlopeFit as SlopeFit, dominant_wavenumber as dominant_wavenumber
from .model.closed_form import radius_from_offset as radius_from_offset, slope_speed as slope_speed
from .errors import TactileInputError as TactileInputError
from .io.files import read_recording as read_recording, read_spectra as read_spectra
from .io.files import write_recording as write_recording, write_spectra as write_spectra
from .inference.pair_fit import (
    Leakage as Leakage,
    PairFit as PairFit,
    fit_pair as fit_pair,
    pair_leakage as pair_leakage,
)
from .model.probe import line_response as line_response, selectivity as selectivity
from .model.r_curve import log_g as log_g, log_r_exact as log_r_exact, log_r_hertz as log_r_hertz
from .model.r_curve import log_r_rough as log_r_rough
from .io.recording import CHANNELS as CHANNELS, Recording as Recording, validate_recording as validate_recording
from .model.sensor import PAPER_SENSOR as PAPER_SENSOR, Sensor as Sensor
from .model.sensor import contact_depth as contact_depth, contact_radius as contact_radius
from .simulation.scene import Scene as Scene, simulate as simulate
from .spectral.estimate import amplitude_ratio as amplitude_ratio, estimate_spectra as estimate_spectra
from .spectral.estimate import usable_band as usable_band, whitened_psd as whitened_psd
from .simulation.texture import Grating as Grating, RandomTexture as RandomTexture, WireNet as WireNet
from .simulation.texture import DirectionalTexture as DirectionalTexture, ModeTexture as ModeTexture

__version__ = "0.1.0"
