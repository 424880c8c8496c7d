"""Property-based fuzzing of the document readers (:mod:`rhs_common.input_files`; hypothesis profile in
``tests/fuzz_settings.py``).

The rule: any bytes in a file, and any text given to the JSON parser, give a value or an
:class:`rhs_common.input_files.InputError` (a ``ValueError``) whose message starts with the file's
name; never another exception (no ``RecursionError``, ``UnicodeDecodeError``, ``OverflowError``,
``yaml.YAMLError``). Inputs: raw bytes; valid JSON and YAML documents; and those documents with bytes
spliced in (bad UTF-8, deep brackets, long integers, aliases).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import fuzz_settings  # noqa: F401  (loads the hypothesis profile)
from hypothesis import given
from hypothesis import strategies as st

from rhs_common.input_files import InputError, parse_json, read_json, read_yaml

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**40), 10**40) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=20)
SPLICES = st.sampled_from([b"\xff", b"\xc3\x28", b"[" * 300, b"{" * 70, b"9" * 5000, b"1e400", b"NaN", b'"',
                           b"*a", b"&a [*a, *a]", b"<<: *a", b"\x00", b"\xef\xbb\xbf", b"- ", b": ", b"!!python/object"])


@st.composite
def documents(draw) -> bytes:
    """Raw bytes, a JSON document, its YAML dump, or either with a splice at a random offset."""
    kind = draw(st.sampled_from(["bytes", "json", "yaml", "spliced"]))
    if kind == "bytes":
        return draw(st.binary(max_size=300))
    value = draw(JSON_VALUES)
    text = json.dumps(value, allow_nan=True).encode()
    if kind == "yaml":
        import yaml

        text = yaml.safe_dump(value).encode()
    if kind != "spliced":
        return text
    at = draw(st.integers(0, len(text)))
    return text[:at] + draw(SPLICES) + text[at:]


def _read(reader, data: bytes, suffix: str):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"doc{suffix}"
        path.write_bytes(data)
        try:
            return reader(path, "doc" + suffix)
        except InputError as exc:
            assert str(exc).startswith("doc" + suffix + ":"), str(exc)
            assert "\n" not in str(exc), str(exc)
            return None


@given(data=documents())
def test_read_json_gives_a_value_or_an_error_naming_the_file(data):
    _read(read_json, data, ".json")


@given(data=documents())
def test_read_yaml_gives_a_value_or_an_error_naming_the_file(data):
    _read(read_yaml, data, ".yml")


@given(text=st.text(max_size=200) | documents().map(lambda b: b.decode("utf-8", "replace")))
def test_parse_json_gives_a_value_or_an_error_naming_the_flag(text):
    try:
        parse_json(text, "--env-kwargs")
    except InputError as exc:
        assert str(exc).startswith("--env-kwargs:"), str(exc)


@given(value=JSON_VALUES)
def test_a_valid_json_document_reads_back_as_written(value):
    """Within the readers' limits (integers of at most 4300 digits here), what json wrote is what is read."""
    text = json.dumps(value)
    try:
        back = parse_json(text, "doc")
    except InputError as exc:
        assert "digits" in str(exc) or "twice" in str(exc), str(exc)  # long integers, a key repeated
        return
    assert json.dumps(back, sort_keys=True) == json.dumps(json.loads(text), sort_keys=True)
