"""A secret typed at the terminal (twice, unechoed) or one line piped on stdin: what the
`--hash-password` / `--hash-pin` commands of the operator screen and the line dashboard read
before they hash it."""

from __future__ import annotations

import getpass
import sys

from station.errors import UserError


def read_secret(what: str) -> str:
    """The secret: asked twice on a terminal (they must agree), else stdin's first line."""
    if sys.stdin.isatty():
        secret = getpass.getpass(f"{what}: ")
        if getpass.getpass("again: ") != secret:
            raise UserError(f"the two {what}s differ; run the command again")
        return secret
    return sys.stdin.readline(1024).rstrip("\r\n")
