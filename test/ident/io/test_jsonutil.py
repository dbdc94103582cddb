"""jsonable: every report/result structure becomes strict JSON (no NaN, no NumPy types)."""

import json

import numpy as np
import yaml

from aeropend_ident.io.jsonutil import jsonable


def test_nested_numpy_and_non_finite_values_become_strict_json() -> None:
    obj = {"std": np.float64("nan"), 3: (np.int64(7), np.array([1.5, np.inf])), "ok": np.bool_(True),
           "nested": [{"x": np.float32(0.25)}]}
    out = jsonable(obj)
    assert out == {"std": None, "3": [7, [1.5, None]], "ok": True, "nested": [{"x": 0.25}]}
    assert json.loads(json.dumps(out, allow_nan=False)) == out
    assert yaml.safe_load(yaml.safe_dump(out)) == out
    assert type(out["3"][0]) is int and type(out["ok"]) is bool
