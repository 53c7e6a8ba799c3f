"""Fuzz: thesis .mat logs and their YAML mapping files, through ``load_flight`` and ``load_mapping``."""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np
import scipy.io
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.errors import QuadModellingError
from quad_modelling.io.loader import load_flight
from quad_modelling.io.matlog import THESIS_VARIABLES, load_mapping, write_matlog
from test.conftest import synthetic_log
from test.fuzz.properties import byte_edits, mutated, outcome, yaml_values

N = 40


def _variables() -> dict:
    with tempfile.TemporaryDirectory() as directory:
        path = write_matlog(synthetic_log(n=N, vehicle="linkquad"), Path(directory) / "base.mat")
        contents = scipy.io.loadmat(path, squeeze_me=True, chars_as_strings=True)
    return {k: v for k, v in contents.items() if not k.startswith("__")}


BASE = _variables()
NAMES = sorted(BASE)

VALUES = st.one_of(
    st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0]).map(lambda v: np.full(N, v)),
    st.tuples(st.integers(0, 3), st.integers(0, 3), st.integers(0, 50)).map(lambda s: np.zeros(s[:2]) if s[2] % 2 else np.zeros(s)),
    st.integers(0, 2 * N).map(lambda n: np.linspace(0.0, 1.0, n)),
    st.just(np.linspace(0.0, 1.0, N) * (1 + 1j)),
    st.text(max_size=10),
    st.just({"a": 1.0}),
    st.just(np.array([[1.0, "x"]], dtype=object)),
    st.floats(),
)


def savemat_bytes(contents: dict, compress: bool) -> bytes:
    stream = io.BytesIO()
    scipy.io.savemat(stream, contents, do_compression=compress, oned_as="column")
    return stream.getvalue()


def check_mat(data: bytes, mapping_text: str | None = None):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "flight.mat"
        path.write_bytes(data)
        mapping = None
        if mapping_text is not None:
            mapping = Path(directory) / "mapping.yaml"
            mapping.write_text(mapping_text)
        result = outcome(lambda: load_flight(path, mapping_file=mapping), mapping if mapping_text is not None else path)
        if isinstance(result, QuadModellingError) and mapping is not None and str(mapping) not in str(result):
            assert str(path) in str(result)
        assert isinstance(result, (FlightLog, QuadModellingError))
        return result


@settings(max_examples=100)
@given(st.dictionaries(st.sampled_from(NAMES), st.one_of(st.none(), VALUES), max_size=3), st.booleans())
def test_edited_variables_give_a_flight_or_one_line(edits, compress):
    contents = dict(BASE)
    for name, value in edits.items():
        if value is None:
            contents.pop(name)
        else:
            contents[name] = value
    check_mat(savemat_bytes(contents, compress))


@settings(max_examples=60)
@given(st.booleans(), st.data())
def test_corrupt_mat_bytes_give_one_line(compress, data):
    original = savemat_bytes(BASE, compress)
    check_mat(mutated(original, data.draw(byte_edits(len(original)), label="edits")))


@settings(max_examples=30)
@given(st.binary(max_size=2000))
def test_random_bytes_give_one_line(data):
    check_mat(data)


def thesis_mapping() -> dict:
    """The thesis variables as a mapping file; u in seconds, the input unit of the base flight's vehicle (linkquad)."""
    frame = {"acc_b": "FRD", "gyro_b": "FRD", "pos_n": "NED", "vel_n": "NED", "euler": "NED"}
    units = {"time": "s", "u": "s", "acc_b": "m/s2", "gyro_b": "rad/s", "pos_n": "m", "vel_n": "m/s", "euler": "rad", "vbat": "V", "omega": "rad/s"}
    doc = {}
    for name, variables in THESIS_VARIABLES.items():
        entry = {"variable": variables[0]} if len(variables) == 1 else {"variables": list(variables)}
        doc[name] = {**entry, "unit": units[name], **({"frame": frame[name]} if name in frame else {})}
    return doc


@settings(max_examples=100)
@given(st.lists(st.tuples(st.sampled_from(list(THESIS_VARIABLES)), st.sampled_from(["variable", "variables", "columns", "unit", "frame", None]), yaml_values), max_size=3))
def test_edited_mapping_gives_a_flight_or_one_line(edits):
    doc = thesis_mapping()
    for field, key, value in edits:
        if key is None:
            doc[field] = value
        elif isinstance(doc.get(field), dict):
            doc[field][key] = value
    check_mat(savemat_bytes(BASE, True), yaml.safe_dump(doc))


@settings(max_examples=60)
@given(st.one_of(yaml_values.map(yaml.safe_dump), st.text(max_size=200)))
def test_any_mapping_document_gives_a_mapping_or_one_line(text):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "mapping.yaml"
        path.write_text(text, errors="surrogatepass")
        result = outcome(lambda: load_mapping(path), path)
        assert isinstance(result, (dict, QuadModellingError))


def test_unedited_base_and_mapping_are_a_flight():
    assert len(check_mat(savemat_bytes(BASE, True), yaml.safe_dump(thesis_mapping()))) == N
