"""The one JSON encoder (brdfscale.files.jsonable / json_text): what every writer did before it
had one — fit.json's non-finite numbers as null and NumPy scalars as Python numbers,
statistics.json's matrices with null where undefined, library.json's NumPy floats, the
topography reader's metadata with dates as ISO text and other objects as text."""

import datetime
import json
import math

import numpy as np
import pytest

from brdfscale.files import json_text, jsonable


def test_non_finite_numbers_become_null_and_numpy_scalars_python_numbers():
    doc = {
        "nan": math.nan,
        "inf": math.inf,
        "-inf": -math.inf,
        "np_nan": np.float64("nan"),
        "np_inf": np.float32("inf"),
        "f64": np.float64(0.25),
        "f32": np.float32(1.5),
        "i64": np.int64(-3),
        "u8": np.uint8(7),
        "bool": np.bool_(True),
        "plain": [1, 2.5, True, None, "text"],
        3: "key",
    }
    out = jsonable(doc)
    assert out == {
        "nan": None,
        "inf": None,
        "-inf": None,
        "np_nan": None,
        "np_inf": None,
        "f64": 0.25,
        "f32": 1.5,
        "i64": -3,
        "u8": 7,
        "bool": True,
        "plain": [1, 2.5, True, None, "text"],
        "3": "key",
    }
    for key, kind in (("f64", float), ("f32", float), ("i64", int), ("u8", int), ("bool", bool)):
        assert type(out[key]) is kind, key
    assert json.loads(json_text(doc)) == out  # the text reads back as the same values
    assert "NaN" not in json_text(doc) and "Infinity" not in json_text(doc)


def test_arrays_and_tuples_become_lists_with_null_where_not_finite():
    covariance = np.array([[1.0, np.nan], [np.inf, 2.0]])
    assert jsonable(covariance) == [[1.0, None], [None, 2.0]]
    assert jsonable((np.arange(3), (1, 2))) == [[0, 1, 2], [1, 2]]
    assert jsonable(np.float64(3.0)[()]) == 3.0


def test_dates_as_iso_text_other_objects_refused_or_given_to_other():
    when = datetime.datetime(2024, 5, 1, 12, 30, tzinfo=datetime.UTC)
    assert jsonable({"t": when, "d": when.date()}) == {"t": "2024-05-01T12:30:00+00:00", "d": "2024-05-01"}

    class Instrument:
        def __str__(self):
            return "profilometer"

    with pytest.raises(TypeError, match="Instrument is not a JSON value"):
        jsonable({"instrument": Instrument()})
    with pytest.raises(TypeError):
        json_text({1, 2})
    assert jsonable({"instrument": Instrument(), "n": np.int32(2)}, other=str) == {"instrument": "profilometer", "n": 2}


def test_json_text_passes_the_options_of_json_dumps():
    assert json_text({"b": 1, "a": "μ"}, indent=1, sort_keys=True, ensure_ascii=False) == '{\n "a": "μ",\n "b": 1\n}'
