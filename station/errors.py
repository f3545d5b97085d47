"""Errors the CLI and UI show to a person as one clear line (exit code 2)."""

from __future__ import annotations


class UserError(Exception):
    """Bad input or a condition the user can fix; the message says what to do."""
