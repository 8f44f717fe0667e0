"""JSON text parsed with orjson where it is importable (about 2x faster than the stdlib json on compact
detector output; never required), and by the stdlib otherwise or where orjson refuses the text."""

from __future__ import annotations

import json
from typing import Any

# The fast parser, or None; benchmarks/keypoint_files.py sets it to None to time the stdlib alone.
try:
    import orjson

    orjson_loads = orjson.loads
except ImportError:  # pragma: no cover - depends on the environment
    orjson_loads = None


def loads(data: bytes) -> Any:
    """Parse JSON with orjson when available; the stdlib decides (and words the error) when orjson refuses."""
    if orjson_loads is not None:
        try:
            return orjson_loads(data)
        except ValueError:  # orjson refuses NaN / Infinity, which the stdlib accepts
            pass
    return json.loads(data)
