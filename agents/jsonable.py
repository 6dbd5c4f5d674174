"""Plain-Python copies of numpy-laden values, and their JSON text.

Study batches, session logs, twin diagnoses and the CLI's ``--json`` output
all serialise dictionaries that hold numpy scalars and arrays; they share
this one conversion, so a value reads back the same wherever it was written.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["jsonable", "to_json"]


def jsonable(value: Any, *, finite: bool = False) -> Any:
    """A copy of ``value`` built only of dict, list, str, int, float, bool and None.

    Mappings become dicts with string keys; lists, tuples, sets and numpy
    arrays become lists; numpy scalars become Python scalars (floats keep
    every bit, so they round-trip exactly); any other object becomes its
    ``repr``.

    Parameters
    ----------
    value : object
    finite : bool, default False
        Replace NaN and infinite floats by None (strict JSON); otherwise they
        are kept and :func:`to_json` writes them as ``NaN`` / ``Infinity``.

    Returns
    -------
    object
    """
    if isinstance(value, Mapping):
        return {str(k): jsonable(v, finite=finite) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [jsonable(v, finite=finite) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist(), finite=finite)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return None if finite and not math.isfinite(value) else value
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return repr(value)


def to_json(value: Any, *, finite: bool = False, sort_keys: bool = True) -> str:
    """JSON text of :func:`jsonable` ``(value, finite=finite)``.

    Parameters
    ----------
    value : object
    finite : bool, default False
        Write non-finite floats as ``null``, giving strict JSON.
    sort_keys : bool, default True
        Sort object keys, so equal values give equal text (and equal hashes).

    Returns
    -------
    str
    """
    return json.dumps(jsonable(value, finite=finite), sort_keys=sort_keys, allow_nan=not finite)
