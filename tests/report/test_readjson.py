"""Bounded reading of the plugin's own JSON files (report/readjson.py): a nesting bomb, an
oversized or special file is refused naming the file; NaN and infinity become strings."""
from __future__ import annotations

import json
import math
import os

import pytest

from pytest_driveeval.core.atomic import (MAX_DEPTH, JSONFileError, finite_json, loads_bounded, nesting_depth,
                                              read_json)

# a fast reader / score / report check: CI runs these at the lowest declared versions (-m smoke)
pytestmark = pytest.mark.smoke

BOMB = "[" * 100_000 + "]" * 100_000


@pytest.mark.parametrize("text, depth", [
    ("1", 0), ("[]", 1), ('{"a": [1, {"b": []}]}', 4),
    ('["[[[[", "{{"]', 1),                 # brackets inside strings do not nest
    ('["a\\"[[[", {"x": "]]"}]', 2),       # nor after an escaped quote
])
def test_nesting_depth_counts_the_brackets_outside_strings(text, depth):
    assert nesting_depth(text) == depth


def test_a_nesting_bomb_is_refused_naming_where_not_a_recursion_error():
    with pytest.raises(JSONFileError) as info:
        loads_bounded('{"results": ' + BOMB + "}", "out/summary.json")
    assert str(info.value).startswith("out/summary.json: JSON nested 100001 levels deep, where the plugin's files "
                                      f"are at most {MAX_DEPTH} levels deep")


def test_nesting_up_to_the_bound_reads():
    text = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert loads_bounded(text, "x") == json.loads(text)
    with pytest.raises(JSONFileError):
        loads_bounded("[" + text + "]", "x")


def test_read_json_names_the_file_and_what_is_wrong(tmp_path):
    (tmp_path / "bomb.json").write_text(BOMB)
    (tmp_path / "big.json").write_text("[" + "1," * 600 + "1]")
    (tmp_path / "cut.json").write_text('{"a": ')
    (tmp_path / "latin.json").write_bytes(b'"\xe9"')
    os.mkfifo(tmp_path / "pipe.json")  # would block a reader that opened it for reading blindly
    cases = {"bomb.json": "JSON nested 100000 levels deep", "big.json": "larger than 1000 bytes",
             "cut.json": "Expecting value", "latin.json": "not UTF-8 text", "pipe.json": "not a regular file",
             "absent.json": "cannot be read: No such file or directory"}
    for name, said in cases.items():
        with pytest.raises(JSONFileError) as info:
            read_json(tmp_path / name, max_bytes=1000 if name == "big.json" else 2 ** 20)
        assert name in str(info.value) and said in str(info.value), str(info.value)


def test_finite_json_writes_nan_and_infinity_as_strings_and_lists_their_keys():
    found: list[str] = []
    value = {"a": [1.0, math.nan], "b": {"c": math.inf, "d": -math.inf}, "e": "NaN", "f": None}
    assert finite_json(value, found=found) == {"a": [1.0, "NaN"], "b": {"c": "Infinity", "d": "-Infinity"},
                                               "e": "NaN", "f": None}
    assert found == ["a[1]", "b.c", "b.d"]
    json.dumps(finite_json(value), allow_nan=False)
