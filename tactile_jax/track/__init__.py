"""A slip followed over time: one update program (``step``) and the sliding-window ``Tracker``."""

from .tracker import Tracker as Tracker, track_recording as track_recording

__all__ = ["Tracker", "track_recording"]
