"""Valid ranges of numeric options, checked where the options come in (`envs.make`,
`DQNConfig`, the `mjxsuite` command) so a value that makes no sense is refused before
anything compiles, with a message naming the option, the value and the valid range."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import numpy as np


class Valid:
    """What a table of valid values holds: `value in valid`, `str(valid)` and `check`."""

    def __contains__(self, value: Any) -> bool:
        raise NotImplementedError

    def check(self, option: str, value: Any) -> Any:
        if value not in self:
            raise ValueError(f"{option} must be {self}, got {value!r}")
        return value


@dataclasses.dataclass(frozen=True)
class Range(Valid):
    """Finite numbers from `low` to `high`; NaN and infinities are never in a range."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False  # (low, ... rather than [low, ...
    integer: bool = False

    def __contains__(self, value: Any) -> bool:
        if isinstance(value, bool) or (self.integer and not isinstance(value, (int, np.integer))):
            return False
        try:
            v = np.asarray(value, dtype=float)  # an array override is checked element by element
        except (TypeError, ValueError):
            return False
        above = v > self.low if self.low_open else v >= self.low
        return bool(np.all(np.isfinite(v) & above & (v <= self.high)))

    def __str__(self) -> str:
        if self.integer:
            return f"an integer >= {self.low:g}"
        if math.isinf(self.low):
            return "a finite number"
        if math.isinf(self.high):
            return f"a finite number {'>' if self.low_open else '>='} {self.low:g}"
        return f"in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"


class Interval(Valid):
    """A pair (low, high) of numbers with low < high, either end possibly infinite: the open
    interval a value must lie in, as Gymnasium's `healthy_z_range=(0.7, inf)`."""

    def __contains__(self, value: Any) -> bool:
        if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or len(value) != 2:
            return False
        if any(isinstance(v, bool) for v in value):
            return False
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            return False
        return low < high  # False for NaN too

    def __str__(self) -> str:
        return "a pair (low, high) of numbers with low < high (either may be +-inf)"


class Flag(Valid):
    """True or False (a switch such as Gymnasium's `terminate_when_unhealthy`)."""

    def __contains__(self, value: Any) -> bool:
        return isinstance(value, (bool, np.bool_))

    def __str__(self) -> str:
        return "True or False"


class OneOf(Valid):
    """One of a fixed set of values (e.g. a dtype's name)."""

    def __init__(self, choices):
        self.choices = tuple(choices)

    def __contains__(self, value: Any) -> bool:
        return value in self.choices

    def __str__(self) -> str:
        return "one of " + ", ".join(repr(c) for c in self.choices)


FINITE = Range()
POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
PROBABILITY = Range(0.0, 1.0)
COUNT = Range(1, integer=True)
NON_NEGATIVE_COUNT = Range(0, integer=True)
INTERVAL = Interval()
FLAG = Flag()


def check_fields(obj: Any, ranges: Mapping[str, Valid]) -> None:
    """Check the fields of a config dataclass against its `RANGES` table."""
    for name, valid in ranges.items():
        valid.check(f"{type(obj).__name__}.{name}", getattr(obj, name))
