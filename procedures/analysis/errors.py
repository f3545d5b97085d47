"""The one exception analysis raises for input it cannot use."""

from __future__ import annotations


class AnalysisError(ValueError):
    """Input an analysis cannot use; the message names the problem and what to do about it."""
