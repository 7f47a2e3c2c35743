"""tactile_jax: slip velocity, contact radius and texture spectra from a vertical-sampling tactile sensor.

Where things are:

- ``model``: the physics as pure jnp functions (depth decay, contact windows, the R curve,
  line probes, the probes' spectral matrix as line integrals over the k-plane);
- ``spectral``: Welch and multitaper spectra, prewhitening, the fit's fixed grid, the usable band;
- ``inference``: the compiled joint fit (data, residuals, solver, pipeline), its options and
  results, model selection; ``uncertainty``: profile likelihood and emcee posteriors;
- ``batch``: a dataset through the same compiled program; ``track``: a slip followed over time
  (a sliding window, one update program); ``simulation``: the scene simulator and changing slips;
- ``contract``: the data contract both sides share (the recording, the result's fields);
- ``io``: recordings (HDF5, NPZ, WAV/FLAC), sensor files, spectra, results and recipes; ``viz``:
  figures and the fit report; ``studies``: comparisons that simulate and plot (compare-r);
  ``cli``: the ``tactile-jax`` commands.

The library never switches on float64 globally: call
``jax.config.update("jax_enable_x64", True)`` first (the CLI does). The line
model (``inference.line_texture``) runs in float64 within its own scope either way.
"""

from .batch.run import BatchSummary as BatchSummary, run_batch as run_batch
from .errors import TactileInputError as TactileInputError
from .inference.fit import fit_record as fit_record, fit_recording as fit_recording, fit_spectra as fit_spectra
from .inference.options import FitOptions as FitOptions
from .inference.pair_fit import PairFit as PairFit, fit_pair as fit_pair
from .inference.result import Estimate as Estimate, FitResult as FitResult, TextureSection as TextureSection
from .io.files import SpectraData as SpectraData, read_recording as read_recording, read_spectra as read_spectra
from .io.files import write_recording as write_recording, write_spectra as write_spectra
from .io.recording import CHANNELS as CHANNELS, Recording as Recording, validate_recording as validate_recording
from .io.results import read_results as read_results, write_results as write_results
from .model.closed_form import SlopeFit as SlopeFit, dominant_wavenumber as dominant_wavenumber
from .model.closed_form import radius_from_offset as radius_from_offset, slope_speed as slope_speed
from .model.probe import line_response as line_response, selectivity as selectivity
from .model.r_curve import log_g as log_g, log_r_exact as log_r_exact, log_r_hertz as log_r_hertz
from .model.r_curve import log_r_rough as log_r_rough
from .model.sensor import PAPER_SENSOR as PAPER_SENSOR, Sensor as Sensor
from .model.sensor import contact_depth as contact_depth, contact_radius as contact_radius
from .simulation.scene import Scene as Scene, simulate as simulate
from .simulation.texture import DirectionalTexture as DirectionalTexture, Grating as Grating
from .simulation.texture import ModeTexture as ModeTexture, RandomTexture as RandomTexture, WireNet as WireNet
from .simulation.texture import StretchedTexture as StretchedTexture
from .spectral.estimate import amplitude_ratio as amplitude_ratio, estimate_spectra as estimate_spectra
from .spectral.estimate import usable_band as usable_band, whitened_psd as whitened_psd
from .status import Status as Status
from .track import Tracker as Tracker, track_recording as track_recording
from .uncertainty.posterior import PosteriorResult as PosteriorResult, run_emcee as run_emcee
from .viz.report import fit_report as fit_report

__version__ = "0.1.0"
