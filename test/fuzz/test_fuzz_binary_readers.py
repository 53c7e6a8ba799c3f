"""Fuzz: MCAP bags (bit flips, metadata.yaml, custom_data notes), PX4 ULog files (flights and the vehicle from the
log's parameters) and model files."""

from __future__ import annotations

import io
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from quad_modelling.core.flight_log import FlightLog
from quad_modelling.core.models.narx import (
    ARRAY_NAMES,
    OUTPUTS,
    NarxConfig,
    NarxModel,
    load_narx,
)
from quad_modelling.core.vehicle import VehicleConfig
from quad_modelling.errors import QuadModellingError
from quad_modelling.io.bag_io import NOTES_KEY, read_recorded, summarize_bag, write_bag
from quad_modelling.io.loader import load_flight
from quad_modelling.io.ulog import topics_of
from quad_modelling.io.ulog_vehicle import (
    LogVehicle,
    vehicle_document,
    vehicle_from_ulog,
    vehicle_yaml,
)
from test.conftest import REPO, synthetic_log
from test.fuzz.properties import byte_edits, mutated, outcome, yaml_values

BAG_DIR = Path(tempfile.mkdtemp(prefix="fuzz-bag-")) / "bag"
write_bag(synthetic_log(n=30), BAG_DIR)
MCAP_NAME = next(BAG_DIR.glob("*.mcap")).name
MCAP = (BAG_DIR / MCAP_NAME).read_bytes()
METADATA = (BAG_DIR / "metadata.yaml").read_text()


def check_bag(mcap: bytes = MCAP, metadata: str = METADATA):
    with tempfile.TemporaryDirectory() as directory:
        bag = Path(directory) / "bag"
        bag.mkdir()
        (bag / MCAP_NAME).write_bytes(mcap)
        (bag / "metadata.yaml").write_text(metadata, errors="surrogatepass")
        result = outcome(lambda: load_flight(bag), bag)
        assert isinstance(result, (FlightLog, QuadModellingError))
        outcome(lambda: summarize_bag(bag), bag)
        outcome(lambda: read_recorded(bag), bag)
        return result


@pytest.mark.slow
@settings(max_examples=60)
@given(byte_edits(len(MCAP)))
def test_corrupt_mcap_gives_a_flight_or_one_line(edits):
    check_bag(mcap=mutated(MCAP, edits))


@pytest.mark.slow
@settings(max_examples=25)
@given(st.one_of(st.text(max_size=40), st.builds(json.dumps, yaml_values)))
def test_any_notes_give_a_flight_or_one_line(notes):
    doc = yaml.safe_load(METADATA)
    doc["rosbag2_bagfile_information"]["custom_data"][NOTES_KEY] = notes
    check_bag(metadata=yaml.safe_dump(doc))


@settings(max_examples=40)
@given(st.one_of(yaml_values.map(yaml.safe_dump), st.text(max_size=200), byte_edits(len(METADATA)).map(lambda e: mutated(METADATA.encode(), e).decode("utf-8", "replace"))))
def test_any_metadata_gives_a_flight_or_one_line(metadata):
    check_bag(metadata=metadata)


ULOGS = sorted((REPO / "test" / "data" / "px4").glob("*.ulg"))


@settings(max_examples=20)
@given(st.sampled_from(ULOGS), st.data())
def test_corrupt_ulog_gives_a_flight_or_one_line(source, data):
    """... and the vehicle from its parameters (``convert --vehicle-from-log``): a vehicle or one line."""
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "flight.ulg"
        original = source.read_bytes()
        path.write_bytes(mutated(original, data.draw(byte_edits(len(original), max_flips=20), label="edits")))
        assert isinstance(outcome(lambda: load_flight(path), path), (FlightLog, QuadModellingError))
        assert isinstance(outcome(lambda: vehicle_from_ulog(path, "v"), path), (LogVehicle, QuadModellingError))


def small_model() -> NarxModel:
    config = NarxConfig(hidden=2, output_delays=2, input_delays=(0, 1), epochs=0, iterations_per_epoch=1)
    k, h, n_u = len(OUTPUTS), 2, 4
    shapes = {"w_u": (k, h, n_u * 2), "w_y": (k, h, 2), "b_1": (k, h), "w_2": (k, h), "b_2": (k,),
              "u_mean": (n_u,), "u_std": (n_u,), "y_mean": (k,), "y_std": (k,), "y_step": (k,)}
    arrays = {name: np.full(shapes[name], 0.5) for name in ARRAY_NAMES}
    return NarxModel(config=config, dt=0.01, vehicle="linkquad", kind="narx", training={}, **arrays)


MODEL = small_model()


def model_bytes(header: dict, arrays: dict) -> bytes:
    stream = io.BytesIO()
    np.savez(stream, header=np.array(json.dumps(header)), **arrays)
    return stream.getvalue()


MODEL_BYTES = model_bytes(MODEL.header(), MODEL.arrays())


def check_model(data: bytes):
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "model.npz"
        path.write_bytes(data)
        result = outcome(lambda: load_narx(path, vehicle="linkquad"), path)
        assert isinstance(result, (NarxModel, QuadModellingError))
        return result


HEADER_KEYS = ["format", "format_version", "kind", "vehicle", "variables", "outputs", "dt", "config", "training"]
CONFIG_KEYS = ["hidden", "output_delays", "input_delays", "epochs", "iterations_per_epoch", "noise_snr_db"]


@settings(max_examples=80)
@given(st.lists(st.tuples(st.sampled_from(HEADER_KEYS + [f"config.{k}" for k in CONFIG_KEYS]), yaml_values), max_size=3),
       st.dictionaries(st.sampled_from(list(ARRAY_NAMES)), st.sampled_from(["drop", "nan", "shape", "text", "int"]), max_size=2))
def test_edited_model_file_gives_a_model_or_one_line(header_edits, array_edits):
    header, arrays = MODEL.header(), MODEL.arrays()
    for key, value in header_edits:
        if key.startswith("config."):
            header["config"] = dict(header["config"]) if isinstance(header["config"], dict) else {}
            header["config"][key.split(".", 1)[1]] = value
        else:
            header[key] = value
    for name, edit in array_edits.items():
        if edit == "drop":
            arrays.pop(name)
        else:
            arrays[name] = {"nan": np.full_like(arrays[name], np.nan), "shape": np.zeros((3, 3)),
                            "text": np.array(["x"]), "int": arrays[name].astype(np.int64)}[edit]
    check_model(model_bytes(header, arrays))


@settings(max_examples=60)
@given(byte_edits(len(MODEL_BYTES)))
def test_corrupt_model_bytes_give_one_line(edits):
    check_model(mutated(MODEL_BYTES, edits))


def test_unedited_bag_and_model_are_valid():
    assert len(check_bag()) == 30
    assert isinstance(check_model(model_bytes(MODEL.header(), MODEL.arrays())), NarxModel)


VEHICLE_KEYS = ["CA_ROTOR_COUNT", "MAV_TYPE", "PWM_MAIN_MIN", "PWM_MAIN_MAX", "PWM_MAIN_DISARM", "HIL_ACT_MIN1", "HIL_ACT_MAX1",
                *(f"CA_ROTOR{n}_{c}" for n in range(4) for c in ("PX", "PY", "KM", "AX", "AY", "AZ")),
                *(f"PWM_MAIN_{kind}{c}" for kind in ("FUNC", "MIN", "MAX", "DIS") for c in range(1, 5))]
"""The parameters :func:`vehicle_from_ulog` reads."""


def _motor_log(source: Path):
    from pyulog import ULog

    ulog = ULog(str(source), message_name_filter_list=["actuator_motors", "actuator_outputs"])
    return topics_of(ulog.data_list)[0], ulog.initial_parameters


MOTOR_LOGS = [_motor_log(source) for source in ULOGS]
PARAMETER_VALUES = st.one_of(st.none(), st.integers(-(2**31), 2**31 - 1), st.floats(width=32, allow_nan=True, allow_infinity=True),
                             st.floats(-1.0, 1.0, width=32))


@settings(max_examples=80)
@given(st.sampled_from(range(len(MOTOR_LOGS))), st.dictionaries(st.sampled_from(VEHICLE_KEYS), PARAMETER_VALUES, max_size=8))
def test_any_rotor_and_pwm_parameters_give_a_vehicle_or_one_line(log, changes):
    """Parameters as a damaged or odd log holds them (None: not logged): a vehicle that loads, or one line."""
    topics, params = MOTOR_LOGS[log]
    params = {**params, **changes}
    params = {k: v for k, v in params.items() if v is not None}
    result = outcome(lambda: vehicle_document(topics, params, "flight.ulg", "v"), "flight.ulg")
    if isinstance(result, LogVehicle):
        assert VehicleConfig.from_dict(yaml.safe_load(vehicle_yaml(result)), "v.yaml").name == "v"
    else:
        assert isinstance(result, QuadModellingError)
