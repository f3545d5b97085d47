"""Who may read the line dashboard: the line users file and what each role may see.

The file (`station line --users FILE`), YAML:

    users:
      - name: Ana Silva
        role: quality            # viewer, quality or engineer
        password_hash: 'scrypt$16384$8$1$...'   # `station line --hash-password`

Hashes are the operator screen's (station/ui/auth.py: scrypt, salted). Roles, each one
seeing what the one before it sees and more:
    viewer    stations, yields, control charts, latest runs
    quality   + capability (Cpk) and run certificates
    engineer  + simulated runs (`?simulated=include`)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from station.errors import UserError
from station.ui.auth import check_hash_format, verify_password

ROLES = ("viewer", "quality", "engineer")
HASH_COMMAND = "station line --hash-password"
_DUMMY_HASH = "scrypt$16384$8$1$" + "00" * 16 + "$" + "00" * 32


def may(role: str, needs: str) -> bool:
    """True when `role` is `needs` or above it (viewer < quality < engineer)."""
    return role in ROLES and ROLES.index(role) >= ROLES.index(needs)


@dataclass(frozen=True)
class LineUser:
    name: str
    role: str
    password_hash: str


@dataclass(frozen=True)
class LineUsers:
    users: tuple[LineUser, ...] = ()

    def check(self, name: str, password: str) -> LineUser | None:
        """The user `name` when `password` is theirs; an unknown name costs the same time."""
        wanted = name.strip().casefold()
        match = next((u for u in self.users if u.name.casefold() == wanted), None)
        ok = verify_password(password, match.password_hash if match else _DUMMY_HASH)
        return match if ok else None


def load_line_users(path: Path) -> LineUsers:
    """The users of `path`; UserError saying what to fix (file, entry, field)."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise UserError(f"{path}: cannot read the line users file ({exc})") from None
    entries = data.get("users") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise UserError(f"{path}: give a list `users:` of name, role and password_hash")
    users = tuple(_user(path, i, e) for i, e in enumerate(entries))
    names = [u.name.casefold() for u in users]
    if len(set(names)) != len(names):
        raise UserError(f"{path}: a user name appears twice; names must be distinct")
    return LineUsers(users)


def _user(path: Path, i: int, entry: object) -> LineUser:
    where = f"{path}: users[{i}]"
    if not isinstance(entry, dict) or set(entry) != {"name", "role", "password_hash"}:
        raise UserError(f"{where}: give exactly name, role and password_hash")
    name, role, stored = (str(entry[k]) for k in ("name", "role", "password_hash"))
    if not name.strip() or not name.isprintable() or len(name) > 64:
        raise UserError(f"{where}: name must be 1-64 printable characters")
    if role not in ROLES:
        raise UserError(f"{where}: role {role!r} is not one of {', '.join(ROLES)}")
    try:
        check_hash_format(stored, f"users[{i}].password_hash", HASH_COMMAND)
    except ValueError as exc:
        raise UserError(f"{path}: {str(exc).replace(' in station.yaml', '')}") from None
    return LineUser(name.strip(), role, stored)
