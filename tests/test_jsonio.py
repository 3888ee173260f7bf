"""jsonio: the one JSON reader, encoder, text form and writer of the project."""

import json
import os

import numpy as np
import pytest
from clothfit.core import jsonio
from clothfit.core.errors import ClothFitError

DATA = {"a": np.float64(0.1), "b": np.arange(3), "c": [np.int64(7), {"d": np.array([[1.5]])}], "e": None}


def test_one_encoder_numpy_as_numbers_and_lists_the_same_text_as_before():
    text = jsonio.dumps(DATA)
    assert json.loads(text) == {"a": 0.1, "b": [0, 1, 2], "c": [7, {"d": [[1.5]]}], "e": None}
    # the text every writer produced before: indent 1, the numpy values converted
    assert text == json.dumps({"a": 0.1, "b": [0, 1, 2], "c": [7, {"d": [[1.5]]}], "e": None}, indent=1)
    assert jsonio.dumps(DATA) == text
    assert jsonio.plain(DATA) == json.loads(text)
    with pytest.raises(TypeError):
        jsonio.dumps({"x": object()})
    with pytest.raises(ValueError):
        jsonio.dumps({"x": float("nan")}, strict=True)
    assert jsonio.dumps({"x": float("nan")}) == '{\n "x": NaN\n}'
    assert jsonio.dumps({"b": 1, "a": 2}, indent=None, sort_keys=True) == '{"a": 2, "b": 1}'


def test_write_json_is_atomic_and_strict_when_asked(tmp_path):
    p = str(tmp_path / "x.json")
    jsonio.write_json(p, DATA)
    assert open(p).read() == jsonio.dumps(DATA) + "\n"
    with pytest.raises(ClothFitError, match=r"cannot write .*x.json: the data is not strict JSON"):
        jsonio.write_json(p, {"x": float("inf")}, strict=True)
    assert json.load(open(p))["e"] is None  # the old file, whole
    assert [n for n in os.listdir(tmp_path)] == ["x.json"]  # no temporary left behind
    jsonio.write_json(p, {"y": np.float32(2.0)})
    assert jsonio.read_json(p) == {"y": 2.0}


def test_read_json_and_loads_are_one_line_errors(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("[1, 2")
    for call, what in (
        (lambda: jsonio.read_json(str(p), "result"), "result"),
        (lambda: jsonio.read_json(str(tmp_path / "none.json"), "result"), "file not found"),
        (lambda: jsonio.loads("{", "scene property"), "scene property: not valid JSON"),
        (lambda: jsonio.loads("[1]", "meta", expect=dict), "meta: expected a JSON object"),
    ):
        with pytest.raises(ClothFitError) as e:
            call()
        assert what in str(e.value) and "\n" not in str(e.value)
    assert jsonio.loads('{"a": 1}', "x", expect=dict) == {"a": 1}
