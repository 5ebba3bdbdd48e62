"""The few functions beyond + - * / that the exact math needs, for three kinds of arrays.

``rwalk.exactmath``, ``rwalk.kinematics.leg_ik`` and the reward terms are written
once, with Python operators (which torch tensors, numpy arrays and floats all
have) and the functions of the namespace ``of(x)`` returns for their argument:

- torch tensors: the batched core;
- numpy arrays: the single env's inverse kinematics (a numpy call costs a
  quarter of a torch call on a few dozen numbers);
- Python floats, with a tuple standing for a vector along the last axis: the
  single env's observation and reward (a float operation costs 1/30 of a numpy call).

Every function here is exact (a comparison, a selection, a table look-up,
abs, floor, copysign) or correctly rounded (sqrt), so the three kinds give the
same bits for the same operations. NaN propagates as in torch: ``maximum``,
``minimum`` and ``clamp`` return NaN when an argument is NaN, and ``sqrt`` of a
negative number is NaN (not an error) for floats too.
"""

from __future__ import annotations

import functools
import math
import operator
from typing import Any

import numpy as np

try:
    import torch
    from torch import Tensor
except ImportError:  # rwalk.deploy runs where torch is absent: numpy arrays and floats only
    torch = None
    Tensor = ()  # isinstance(x, ()) is always False

F64 = torch.float64 if torch is not None else None


class Table:
    """A constant table of float rows, looked up by a float index array (exact)."""

    def __init__(self, rows: tuple[tuple[float, ...], ...]) -> None:
        self.rows = rows
        self.columns = [np.ascontiguousarray(c) for c in np.array(rows, dtype=np.float64).T]
        """The columns as numpy (1-D look-ups are the cheapest). Each shape: (R,)."""

    @functools.lru_cache(maxsize=8)  # noqa: B019 (tables live as long as the module)
    def tensors(self, device: torch.device) -> tuple[Tensor, ...]:
        """The columns as float64 on ``device``. Each shape: (R,)."""
        columns = zip(*self.rows, strict=True)
        return tuple(torch.tensor(column, dtype=F64, device=device) for column in columns)


if torch is not None:  # the batched core's namespace

    def _ieee_sqrt(x: Tensor) -> Tensor:
        """Correctly rounded sqrt. torch.sqrt of float64 on the CPU goes through MKL's vector
        math, which rounds ~1% of results the other way (and may pick its code by CPU);
        numpy's is the CPU's sqrt instruction, which IEEE-754 requires to round correctly."""
        if x.device.type != "cpu" or x.requires_grad or x.dtype != F64:
            return torch.sqrt(x)  # not covered: exactness is a CPU, float64, no-grad promise
        return torch.from_numpy(np.asarray(np.sqrt(x.numpy())))  # a 0-d result is a scalar

    class TorchOps:
        """Functions on torch tensors (float64 unless said)."""

        sqrt = staticmethod(_ieee_sqrt)
        floor = staticmethod(torch.floor)
        where = staticmethod(torch.where)
        maximum = staticmethod(torch.maximum)
        minimum = staticmethod(torch.minimum)
        copysign = staticmethod(torch.copysign)
        signbit = staticmethod(torch.signbit)

        @staticmethod
        def as_f64(x: Any) -> Tensor:
            return torch.as_tensor(x, dtype=F64)

        @staticmethod
        def broadcast(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
            return torch.broadcast_tensors(a, b)  # type: ignore[return-value]

        @staticmethod
        def clamp(x: Tensor, low: Any = None, high: Any = None) -> Tensor:
            return torch.clamp(x, low, high)

        @staticmethod
        def nan_to(x: Tensor, value: float) -> Tensor:
            """x with NaN replaced by value; overwrites x (pass a temporary)."""
            return x.nan_to_num_(nan=value)

        @staticmethod
        def as_float(flags: Tensor) -> Tensor:
            return flags.to(F64)

        @staticmethod
        def not_equal(a: Tensor, b: Tensor) -> Tensor:
            return a != b

        @staticmethod
        def select(flags: Tensor, if_true: float, if_false: float) -> Tensor:
            values = torch.tensor([if_false, if_true], dtype=F64, device=flags.device)
            return values[flags.long()]

        @staticmethod
        def lookup(table: Table, index: Tensor) -> tuple[Tensor, ...]:
            """Columns of the rows at float indices. Each shape: index's."""
            rows = index.long().flatten()
            return tuple(
                column.index_select(0, rows).reshape(index.shape)
                for column in table.tensors(index.device)
            )

        @staticmethod
        def stack(items: tuple[Tensor, ...] | list[Tensor], axis: int = -1) -> Tensor:
            return torch.stack(tuple(items), dim=axis)

        @staticmethod
        def unstack(x: Tensor) -> tuple[Tensor, ...]:
            return x.unbind(-1)

        @staticmethod
        def unstack_first(x: Tensor) -> tuple[Tensor, ...]:
            return x.unbind(0)

        @staticmethod
        def expand(x: Tensor, shape: tuple[int, ...]) -> Tensor:
            """x broadcast to ``shape``, as a new writable tensor."""
            return x.expand(*shape).clone()

        @staticmethod
        def all_last(x: Tensor) -> Tensor:
            return x.all(dim=-1)

else:
    TorchOps = None  # no torch: nothing is a tensor


class NumpyOps:
    """Functions on numpy arrays (float64 unless said)."""

    sqrt = staticmethod(np.sqrt)
    floor = staticmethod(np.floor)
    where = staticmethod(np.where)
    maximum = staticmethod(np.maximum)
    minimum = staticmethod(np.minimum)
    copysign = staticmethod(np.copysign)
    signbit = staticmethod(np.signbit)

    @staticmethod
    def as_f64(x: Any) -> np.ndarray:
        return np.asarray(x, dtype=np.float64)

    @staticmethod
    def broadcast(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.broadcast_arrays(a, b)  # type: ignore[return-value]

    @staticmethod
    def clamp(x: np.ndarray, low: Any = None, high: Any = None) -> np.ndarray:
        if low is not None:
            x = np.maximum(x, low)
        return x if high is None else np.minimum(x, high)

    @staticmethod
    def nan_to(x: np.ndarray, value: float) -> np.ndarray:
        """x with NaN replaced by value; overwrites x (pass a temporary)."""
        np.copyto(x, value, where=x != x)  # a third of np.where's cost
        return x

    @staticmethod
    def as_float(flags: np.ndarray) -> np.ndarray:
        return flags  # a bool array is promoted to float64 by the arithmetic it meets

    @staticmethod
    def not_equal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a != b

    @staticmethod
    def select(flags: np.ndarray, if_true: float, if_false: float) -> np.ndarray:
        return np.where(flags, if_true, if_false)

    @staticmethod
    def lookup(table: Table, index: np.ndarray) -> tuple[np.ndarray, ...]:
        rows = index.astype(np.intp)
        return tuple([column[rows] for column in table.columns])

    @staticmethod
    def stack(items: tuple[np.ndarray, ...] | list[np.ndarray], axis: int = -1) -> np.ndarray:
        """Same-shape items stacked along a new first (axis=0) or last axis (-1), C-contiguous
        (ufuncs on transposed views cost twice as much). np.stack costs ~4 µs in Python."""
        if axis == 0:
            return np.array(items)  # ~1 µs
        first = items[0]
        out = np.empty((*first.shape, len(items)))
        for k, item in enumerate(items):
            out[..., k] = item
        return out

    @staticmethod
    def unstack(x: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(x[..., k] for k in range(x.shape[-1]))

    @staticmethod
    def unstack_first(x: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(x)

    @staticmethod
    def expand(x: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        """x broadcast to ``shape``, as a new writable array."""
        return np.broadcast_to(x, shape).copy()

    @staticmethod
    def all_last(x: np.ndarray) -> np.ndarray:
        return x.all(axis=-1)


class FloatOps:
    """Functions on Python floats; a tuple is a vector along the last axis."""

    copysign = staticmethod(math.copysign)

    @staticmethod
    def sqrt(x: float) -> float:
        return math.sqrt(x) if x >= 0.0 else math.nan

    @staticmethod
    def floor(x: float) -> float:
        return float(math.floor(x)) if math.isfinite(x) else x

    @staticmethod
    def maximum(a: float, b: float) -> float:
        return a if a > b else b if a <= b else math.nan

    @staticmethod
    def minimum(a: float, b: float) -> float:
        return a if a < b else b if a >= b else math.nan

    @staticmethod
    def signbit(x: float) -> bool:
        return math.copysign(1.0, x) < 0.0

    @staticmethod
    def as_f64(x: Any) -> Any:
        return x

    @staticmethod
    def broadcast(a: float, b: float) -> tuple[float, float]:
        return a, b

    @staticmethod
    def clamp(x: float, low: float | None = None, high: float | None = None) -> float:
        if low is not None and x < low:
            x = low
        if high is not None and x > high:
            x = high
        return x  # NaN fails both comparisons and stays NaN

    @staticmethod
    def nan_to(x: float, value: float) -> float:
        return value if x != x else x

    @staticmethod
    def as_float(flag: bool) -> bool:
        return flag  # True * 2.0 == 2.0

    @staticmethod
    def not_equal(a: tuple, b: tuple) -> tuple[bool, ...]:
        return tuple(map(operator.ne, a, b))

    @staticmethod
    def select(flags: tuple[bool, ...], if_true: float, if_false: float) -> tuple[float, ...]:
        return tuple(if_true if flag else if_false for flag in flags)

    @staticmethod
    def lookup(table: Table, index: float) -> tuple[float, ...]:
        return table.rows[int(index)]

    @staticmethod
    def stack(items: tuple[float, ...] | list[float], axis: int = -1) -> tuple[float, ...]:
        return tuple(items)

    @staticmethod
    def unstack(x: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(x)

    @staticmethod
    def all_last(x: tuple[bool, ...]) -> bool:
        return all(x)


def of(*args: Any) -> type[TorchOps] | type[NumpyOps] | type[FloatOps]:
    """The namespace for these arguments: torch if any is a tensor, else numpy if any
    is an array, else floats (a tuple counts as a vector of floats)."""
    kind = FloatOps
    for arg in args:
        if isinstance(arg, Tensor):
            return TorchOps
        if isinstance(arg, np.ndarray):
            kind = NumpyOps
    return kind
