"""Typed errors. Every message is one line that names the source and the problem."""

from __future__ import annotations

from .status import Status

__all__ = ["TactileInputError"]


class TactileInputError(ValueError):
    """Bad input (file, array or setting): ``"<source>: <problem>"`` on one line.

    ``code`` is the record's status in a batch row (a ``status.Status`` of the input
    kind: ``unreadable``, ``not_recording``, ``missing_key``, ``bad_shape``, ``nonfinite``,
    ``bad_fs``, ``bad_depths``, ``too_short``, ``bad_setting``, ``bad_input``).
    """

    def __init__(self, problem: str, *, source: str | None = None, code: str = "bad_input"):
        self.problem = " ".join(str(problem).split())  # force one line
        self.source = None if source is None else str(source)
        self.code = Status(code)
        super().__init__(f"{self.source}: {self.problem}" if self.source else self.problem)

    def with_source(self, source) -> "TactileInputError":
        """The same error naming ``source`` (kept if it already names one)."""
        if self.source is not None:
            return self
        return TactileInputError(self.problem, source=source, code=self.code)
