"""Every status a result row can carry, as one enumeration.

A ``Status`` is a ``str``: ``row["status"] == "ok"`` and ``Status.OK == "ok"``
both hold, and files keep the plain value. ``FIT_CODES`` fixes the integer code
that the compiled pipeline returns (``inference.core.Summary.status``).
"""

from __future__ import annotations

import enum

__all__ = ["Status", "FIT_CODES", "FIT_RAN", "TRANSIENT"]


class Status(str, enum.Enum):
    """Outcome of one record: a fit's verdict, an input error's code or a failure of the machinery."""

    # a fit ran and gave values
    OK = "ok"
    POOR_FIT = "poor_fit"              # reduced chi-square above the limit: the model does not describe the spectra
    NOT_CONVERGED = "not_converged"
    UNDETERMINED = "undetermined"      # a fit that cannot determine a speed (a grating's component along its ridges)
    # a window of a tracked recording (``track``)
    NO_SLIP = "no_slip"                # the probes hear no texture moving: a still contact, or none
    SLIP_START = "slip_start"          # a slip starts inside the window: its values mix the still part and the slip
    SLIP_STOP = "slip_stop"            # a slip ends inside the window
    SLIP_CHANGE = "slip_change"        # the slip changes inside the window (the updates' misfit rose): no values
    # no values
    NO_BAND = "no_band"                # too few usable bins
    FAILED = "failed"                  # non-finite values, or an exception inside the fit
    UNSUPPORTED = "unsupported"        # an option the fit does not offer
    # bad input (``errors.TactileInputError.code``)
    BAD_INPUT = "bad_input"
    UNREADABLE = "unreadable"
    NOT_RECORDING = "not_recording"
    MISSING_KEY = "missing_key"
    BAD_SHAPE = "bad_shape"
    NONFINITE = "nonfinite"
    BAD_FS = "bad_fs"
    BAD_DEPTHS = "bad_depths"
    TOO_SHORT = "too_short"
    BAD_SETTING = "bad_setting"
    # the machinery
    FIT_ERROR = "fit_error"            # an exception while fitting one record of several
    WORKER_ERROR = "worker_error"      # a batch chunk lost (redone on resume)

    def __str__(self) -> str:
        return self.value


#: the compiled pipeline's integer status codes, in order
FIT_CODES = (Status.OK, Status.NO_BAND, Status.NOT_CONVERGED, Status.POOR_FIT, Status.FAILED)
#: statuses of a fit that ran and produced values
FIT_RAN = (Status.OK, Status.NOT_CONVERGED, Status.POOR_FIT, Status.UNDETERMINED)
#: statuses a batch redoes on resume
TRANSIENT = (Status.WORKER_ERROR,)
