"""Fuzz: vehicle configs as a user edits them (any value at any key, bytes, alias bombs), through ``load_vehicle``."""

from __future__ import annotations

import tempfile
from pathlib import Path

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from quad_modelling.core.vehicle import VehicleConfig, load_vehicle, vehicle_dir
from quad_modelling.errors import QuadModellingError
from test.fuzz.properties import byte_edits, mutated, outcome, yaml_values

SHIPPED = (vehicle_dir() / "crazyflie21.yaml").read_text()
DOC = yaml.safe_load(SHIPPED)


def paths(doc, prefix=()):
    """Every key path of a nested document."""
    yield prefix
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from paths(value, (*prefix, key))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            yield from paths(value, (*prefix, i))


KEY_PATHS = [p for p in paths(DOC) if p]


def edited(doc, path, value):
    """A deep copy of ``doc`` with ``path`` set to ``value`` (removed when value is the sentinel ``...``)."""
    doc = yaml.safe_load(yaml.safe_dump(doc))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if value is ...:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return doc


def check(data: bytes):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "vehicle.yaml"
        path.write_bytes(data)
        result = outcome(lambda: load_vehicle(path), path)
        assert isinstance(result, (VehicleConfig, QuadModellingError))
        return result


@settings(max_examples=80)
@given(st.lists(st.tuples(st.sampled_from(KEY_PATHS), st.one_of(st.just(...), yaml_values)), min_size=1, max_size=3))
def test_edited_vehicle_gives_a_config_or_one_line(edits):
    doc = DOC
    for path, value in edits:
        try:
            doc = edited(doc, path, value)
        except (KeyError, IndexError, TypeError):  # an earlier edit removed or replaced the parent
            continue
    check(yaml.safe_dump(doc, allow_unicode=True).encode())


@settings(max_examples=60)
@given(byte_edits(len(SHIPPED.encode())))
def test_corrupt_vehicle_bytes_give_one_line(edits):
    check(mutated(SHIPPED.encode(), edits))


@settings(max_examples=40)
@given(yaml_values)
def test_any_document_gives_a_config_or_one_line(doc):
    check(yaml.safe_dump(doc).encode())


def test_shipped_config_is_the_valid_base():
    assert check(SHIPPED.encode()).name == "crazyflie21"
