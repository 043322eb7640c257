"""Validation shared by the control layers' frozen configurations."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any


def require_positive(owner: str, config: Any, names: Iterable[str], zero_ok: Iterable[str] = ()) -> None:
    """Each field ``names`` of ``config`` is a finite number > 0 (>= 0 for those in ``zero_ok``),
    else a ValueError naming ``owner`` and the field."""
    zero = set(zero_ok)
    for name in names:
        v = getattr(config, name)
        low_ok = v >= 0 if name in zero else v > 0
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (low_ok and v < math.inf):
            what = "a finite number >= 0" if name in zero else "a positive finite number"
            raise ValueError(f"{owner} {name} must be {what}, got {v!r}")
