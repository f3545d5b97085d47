"""Input checks shared by the analysis modules: each failure names the problem and the fix."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis.errors import AnalysisError


def finite_1d(values: ArrayLike, name: str, min_len: int = 1) -> NDArray[np.float64]:
    """A 1-D float64 copy of `values`; raises if not 1-D, too short or holding NaN/inf."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise AnalysisError(f"{name} must be a 1-D array of samples, got shape {arr.shape}")
    if arr.size < min_len:
        raise AnalysisError(
            f"{name} has {arr.size} samples, at least {min_len} are needed: record longer"
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        first = int(np.argmax(bad))
        raise AnalysisError(
            f"{name} holds {int(bad.sum())} NaN or infinite value(s), first at index {first}: "
            "remove or repair those samples"
        )
    return arr


def positive(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise AnalysisError(f"{name} must be a positive finite number, got {value!r}")
    return v


def non_negative(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0.0:
        raise AnalysisError(f"{name} must be a non-negative finite number, got {value!r}")
    return v


def monotonic_time(time_s: NDArray[np.float64], name: str = "time_s") -> None:
    """Raise unless time strictly increases (a sort or a clock reset upstream breaks it)."""
    steps = np.diff(time_s)
    bad = steps <= 0.0
    if bad.any():
        i = int(np.argmax(bad))
        raise AnalysisError(
            f"{name} is not strictly increasing at index {i + 1} "
            f"({time_s[i]!r} then {time_s[i + 1]!r}): sort the record or drop repeated samples"
        )


def same_length(**arrays: NDArray[np.float64]) -> int:
    lengths = {k: int(np.shape(v)[0]) for k, v in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise AnalysisError(f"arrays must have one length, got {lengths}")
    return next(iter(lengths.values()))
