"""Helpers for numpy arrays: read-only copies and value equality for frozen dataclasses, and
nearest-pixel resampling of images."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import DTypeLike, NDArray


def frozen_array(values: Any, dtype: DTypeLike) -> NDArray[Any]:
    """A read-only array copy of `values` with `dtype`, safe to keep in a frozen dataclass."""
    array = np.array(values, dtype=dtype, copy=True)
    array.setflags(write=False)
    return array


def values_equal(a: Any, b: Any) -> bool:
    """Deep equality in which arrays compare by value and NaN equals NaN."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if a_arr.shape != b_arr.shape or a_arr.dtype != b_arr.dtype:
            return False
        return bool(np.array_equal(a_arr, b_arr, equal_nan=a_arr.dtype.kind == "f"))
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return type(a) is type(b) and all(
            values_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(values_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(values_equal(a[k], b[k]) for k in a)
    return bool(a == b)


class ArrayValueEq:
    """Mixin giving dataclasses holding arrays a value `__eq__` (arrays by value, NaN == NaN)."""

    def __eq__(self, other: object) -> bool:
        return values_equal(self, other)

    __hash__ = None  # type: ignore[assignment]


def nearest_indices(size: int, source_size: int) -> NDArray[np.intp]:
    """For each of `size` output pixels along one axis, the source pixel (of `source_size`) whose
    area holds the output pixel's centre."""
    centres = (np.arange(size) + 0.5) * source_size / size
    return np.minimum(centres.astype(np.intp), source_size - 1)
