"""Opening an HDF5 file the station did not just write (a run folder's raw.h5), with bounds.

A truncated or corrupt file must be refused at once, in one line. Two things made it hang:
HDF5's SWMR reader retries a metadata block whose checksum fails 100 times with growing sleeps
(minutes, in C, deaf to signals), and a superblock that promises more bytes than the file
has sends every read past the end. So, before HDF5 sees the file:

- its first bytes must be HDF5's signature and its superblock's end-of-file address must lie
  within the file (a truncated file is named with both sizes);
- it is opened for SWMR reading (a run that was killed leaves its file marked open for
  writing, which only a SWMR reader may open) with one metadata read attempt, set through
  the HDF5 library h5py itself loaded; where that library cannot be reached, it is opened
  without SWMR (a killed run's file is then refused, in one line).
"""

from __future__ import annotations

import ctypes
import glob
import os
import struct
from pathlib import Path
from typing import Any

import h5py
from h5py import h5f, h5p

from common.regular_file import NotARegularFile, open_regular

SIGNATURE = b"\x89HDF\r\n\x1a\n"
_MESSAGE_CHARS = 300
_UNREADABLE = "raw data file cannot be read"


class H5InputError(ValueError):
    """The file is not a readable HDF5 file; the message is one line naming it."""


def one_line(exc: BaseException, limit: int = _MESSAGE_CHARS) -> str:
    """An exception's text on one line, at most `limit` characters (h5py's errors carry
    multi-line HDF5 stacks)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_header(path: Path) -> None:
    """The signature, and (superblock versions 2 and 3) the stored end of file against the
    file's size; H5InputError if either is wrong."""
    try:
        size = path.stat().st_size
        with open_regular(path) as fh:
            head = fh.read(48)
    except NotARegularFile as exc:
        raise H5InputError(f"{exc}; give a raw.h5 file") from None
    except OSError as exc:
        raise H5InputError(f"{path}: {_UNREADABLE} ({exc.strerror or exc})") from None
    if len(head) < len(SIGNATURE) or not head.startswith(SIGNATURE):
        what = "an empty file" if size == 0 else "not HDF5: no HDF5 signature"
        raise H5InputError(f"{path}: {_UNREADABLE} ({what})")
    if len(head) < 12:
        raise H5InputError(f"{path}: {_UNREADABLE} (truncated to {size} bytes)")
    version, size_of_offsets = head[8], head[9]
    if version in (2, 3) and size_of_offsets == 8:
        if len(head) < 36:
            raise H5InputError(f"{path}: {_UNREADABLE} (truncated to {size} bytes)")
        (stored_eof,) = struct.unpack_from("<Q", head, 28)
        if size < stored_eof:
            raise H5InputError(
                f"{path}: {_UNREADABLE} (truncated: {size} of its {stored_eof} bytes)"
            )


def open_h5(path: Path) -> h5py.File:
    """`path` opened for reading (see the module docstring); H5InputError in one line if it
    cannot be. The caller closes it."""
    path = Path(path)
    check_header(path)
    try:
        fapl = _fapl_one_attempt()
        if fapl is not None:
            fid = h5f.open(os.fsencode(path), h5f.ACC_RDONLY | h5f.ACC_SWMR_READ, fapl=fapl)
            return h5py.File(fid)
        return h5py.File(path, "r")
    except (OSError, RuntimeError, ValueError, KeyError) as exc:
        raise H5InputError(f"{path}: {_UNREADABLE} ({one_line(exc)})") from None


_HDF5: list[Any] = []  # the library handle, looked up once ([None] if not found)


def _fapl_one_attempt() -> Any:
    """A file-access property list for SWMR reading with one metadata read attempt, or None
    when the HDF5 library's H5Pset_metadata_read_attempts cannot be reached."""
    if not _HDF5:
        _HDF5.append(_find_library())
    lib = _HDF5[0]
    if lib is None:
        return None
    fapl = h5p.create(h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5f.LIBVER_LATEST, h5f.LIBVER_LATEST)
    if lib.H5Pset_metadata_read_attempts(fapl.id, 1) < 0:
        return None
    return fapl


def _find_library() -> Any:
    """The libhdf5 h5py uses: the wheel's own copy (h5py.libs), else the process's symbols
    (a distribution's h5py links the system library)."""
    here = Path(h5py.__file__).resolve().parent
    candidates = [p for p in glob.glob(str(here.parent / "h5py.libs" / "libhdf5-*.so*"))
                  if "_hl" not in Path(p).name]
    for name in [*candidates, None]:
        try:
            lib = ctypes.CDLL(name)
            fn = lib.H5Pset_metadata_read_attempts
        except (OSError, AttributeError):
            continue
        fn.argtypes = [ctypes.c_int64, ctypes.c_uint]
        fn.restype = ctypes.c_int
        return lib
    return None
