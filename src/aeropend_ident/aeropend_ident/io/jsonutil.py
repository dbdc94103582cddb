"""JSON-safe conversion of result structures (reports, model files, benchmark results)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def jsonable(obj: Any) -> Any:
    """Copy of ``obj`` that ``json.dumps(..., allow_nan=False)`` and ``yaml.safe_dump`` accept.

    Dict keys become strings, tuples lists, NumPy scalars and arrays Python numbers and lists,
    and non-finite floats ``None`` (JSON null): a null standard error means "not available"
    (the parameter sits on a bound, or the data do not determine it). Other objects are
    returned unchanged.

    Parameters
    ----------
    obj : Any
        Nested dicts, lists, tuples, NumPy arrays / scalars and plain values.

    Returns
    -------
    Any
        The converted structure.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
