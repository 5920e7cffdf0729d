"""Bad input and exposure: hostile command messages (fuzzed and by hand), CURVE keys.

(Its tests with real peers: tests/system/test_security.py.)
"""

from __future__ import annotations

import json

import pytest
from fluidsense.controller.requests.server import too_deep


@pytest.mark.parametrize("raw, deep", [
    (b"[" * 33 + b"]" * 33, True),
    (b"[" * 32 + b"]" * 32, False),
    (b'{"a": [[{"b": [1]}]]}' * 40, False),  # many brackets, shallow
    (json.dumps({"s": "[" * 100}).encode(), False),
    (json.dumps({"s": '\\"' + "[" * 100}).encode(), False),  # an escaped quote does not end the string
    (b'["\\\\"' + b", [" * 40 + b"]" * 40 + b"]", True),  # an escaped backslash does
])
def test_depth_is_counted_outside_strings(raw, deep):
    assert too_deep(raw) is deep
