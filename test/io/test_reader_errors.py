"""Each reader crash the fuzz suite (test/fuzz/) found or issue 18 listed, as a plain example with its exact one-line message."""

from __future__ import annotations

import gzip
import io
import json
import os
import time
import warnings
import zipfile

import numpy as np
import pytest
import scipy.io
import yaml
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin

from quad_modelling.core.models import model_files
from quad_modelling.core.models.narx import load_narx
from quad_modelling.core.vehicle import load_vehicle
from quad_modelling.errors import BagError, ConfigError, DataError, ModelError, reason
from quad_modelling.io.bag_io import NOTES_KEY, TYPESTORE, write_bag
from quad_modelling.io.loader import load_flight
from quad_modelling.io.matlog import load_mapping, write_matlog
from test.conftest import FIXTURES, REPO, synthetic_log
from test.fuzz.test_fuzz_binary_readers import MODEL, model_bytes

LINES = gzip.open(FIXTURES / "nanobench" / "B7_oval_medium_rep2_first1000.csv.gz", "rt").read().splitlines()[:31]
HEADER = LINES[0].split(",")
BOMB = "".join(f"{a}: &{a} [{', '.join([f'*{b}'] * 9 if b else ['x'] * 9)}]\n" for a, b in zip("abcdefgh", ["", *"abcdefg"]))


def refusal(error: type, call, *args, **kwargs) -> str:
    """The message of the ``error`` that ``call(*args, **kwargs)`` raises."""
    with pytest.raises(error) as info:
        call(*args, **kwargs)
    return str(info.value)


def csv_with(tmp_path, row: int, column: str, value: str, name: str = "flight.csv"):
    lines = [line.split(",") for line in LINES]
    lines[row][HEADER.index(column)] = value
    path = tmp_path / name
    path.write_text("\n".join(",".join(cells) for cells in lines) + "\n")
    return path


def test_project_errors_are_one_line_whatever_went_in():
    assert str(DataError("a.csv: column\nt\r\nrow 3")) == "a.csv: column t row 3"
    assert isinstance(BagError("x\ny"), OSError) and str(BagError("x\ny")) == "x y"
    assert reason(ValueError("line one\n  line two")) == "ValueError: line one line two"
    assert reason(ValueError("x" * 500)) == "ValueError: " + "x" * 197 + "..."


def test_header_only_csv_is_refused(tmp_path):
    path = tmp_path / "header.csv"
    path.write_text(LINES[0] + "\n")
    assert refusal(DataError, load_flight, path) == f"{path}: no data rows after the header"


def test_corrupt_gzip_is_one_line(tmp_path):
    data = gzip.compress("\n".join(LINES).encode(), mtime=0)
    truncated = tmp_path / "truncated.csv.gz"
    truncated.write_bytes(data[: len(data) // 2])
    assert refusal(DataError, load_flight, truncated) == f"{truncated}: cannot read (EOFError: Compressed file ended before the end-of-stream marker was reached)"
    flipped = tmp_path / "flipped.csv.gz"
    flipped.write_bytes(data[:20] + bytes([data[20] ^ 0xFF]) + data[21:])
    assert refusal(DataError, load_flight, flipped).startswith(f"{flipped}: cannot read (error: Error -3 while decompressing data: ")


def test_time_of_1e300_is_refused_without_printing_it(tmp_path):
    path = csv_with(tmp_path, 10, "t", "1e300")
    assert refusal(DataError, load_flight, path) == f"{path}: time at sample 10 of 30 is 1e+300 s, beyond ±9.223e+09 s (int64 nanosecond stamps): corrupt time base"


def test_duplicate_and_non_utf8_csv(tmp_path):
    twice = tmp_path / "twice.csv"
    twice.write_text(LINES[0] + ",qw\n" + "\n".join(line + ",1" for line in LINES[1:]) + "\n")
    assert refusal(DataError, load_flight, twice) == f"{twice}: NanoBench column(s) ['qw'] appear more than once in the header"
    latin = tmp_path / "latin.csv"
    latin.write_bytes(LINES[0].encode() + b"\n\xff\xfe,1\n")
    assert refusal(DataError, load_flight, latin) == f"{latin}: not UTF-8 text (byte {len(LINES[0]) + 1} of a line: b'\\xff')"


def test_zero_byte_and_complex_mat_files(tmp_path):
    empty = tmp_path / "empty.mat"
    empty.write_bytes(b"")
    assert refusal(DataError, load_flight, empty, vehicle="linkquad") == f"{empty}: not a readable MATLAB file (MatReadError: Mat file appears to be truncated)"
    write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "good.mat")
    contents = {k: v for k, v in scipy.io.loadmat(tmp_path / "good.mat").items() if not k.startswith("__")}
    contents["XN"] = contents["XN"] * (1 + 1j)
    scipy.io.savemat(tmp_path / "complex.mat", contents)
    assert refusal(DataError, load_flight, tmp_path / "complex.mat") == f"{tmp_path / 'complex.mat'}: variable(s) ['XN'] of field pos_n are complex-valued, expected real numbers"


def test_mat_meta_json_and_vehicle_of_the_wrong_type(tmp_path):
    write_matlog(synthetic_log(vehicle="linkquad"), tmp_path / "good.mat")
    contents = {k: v for k, v in scipy.io.loadmat(tmp_path / "good.mat").items() if not k.startswith("__")}
    scipy.io.savemat(tmp_path / "list.mat", {**contents, "meta_json": "[1, 2]"})
    assert refusal(DataError, load_flight, tmp_path / "list.mat") == f"{tmp_path / 'list.mat'}: variable meta_json must hold a JSON object, got list"
    scipy.io.savemat(tmp_path / "deep.mat", {**contents, "meta_json": "[" * 100_000 + "]" * 100_000})
    assert refusal(DataError, load_flight, tmp_path / "deep.mat") == f"{tmp_path / 'deep.mat'}: variable meta_json nests deeper than JSON can be read"
    scipy.io.savemat(tmp_path / "number.mat", {**contents, "vehicle": np.array([1.0, 2.0])})
    assert refusal(DataError, load_flight, tmp_path / "number.mat") == f"{tmp_path / 'number.mat'}: variable vehicle must be a vehicle config name (text), got a ndarray"


@pytest.mark.parametrize("entry, message", [
    ({"variable": "u1", "columns": ["a"], "unit": "1"}, "field 'u': 'columns' must list 4 non-negative 0-based column numbers, got ['a']"),
    ({"variable": "u1", "columns": 3, "unit": "1"}, "field 'u': 'columns' must list 4 non-negative 0-based column numbers, got 3"),
    ({"variable": "u1", "columns": [-1], "unit": "1"}, "field 'u': 'columns' must list 4 non-negative 0-based column numbers, got [-1]"),
    ({"variables": 5, "unit": "1"}, "field 'u': 'variables' must list 4 variable names, got 5"),
    ({"variable": ["u1"], "unit": "1"}, "field 'u': 'variable' must be one variable name, got \"['u1']\""),
    ({"variable": "u1", "unit": ["1"]}, "field 'u' has unknown unit \"['1']\"; known: ['s', 'ms', 'us', 'ns', 'm', 'mm', 'm/s', 'm/s2', 'g', 'rad', 'deg', 'rad/s', 'deg/s', 'rad/s2', 'deg/s2', 'V', '1', 'PWM']"),
])
def test_malformed_mapping_entries(tmp_path, entry, message):
    path = tmp_path / "mapping.yaml"
    path.write_text(yaml.safe_dump({"time": {"variable": "time", "unit": "s"}, "u": entry}))
    assert refusal(ConfigError, load_mapping, path) == f"{path}: {message}"


def test_non_utf8_yaml_is_one_line(tmp_path):
    path = tmp_path / "latin.yaml"
    path.write_bytes(b"name: \xff\xfe\n")
    assert refusal(ConfigError, load_vehicle, path) == f"{path}: vehicle config is not UTF-8 text (byte 6: b'\\xff')"
    assert refusal(ConfigError, load_mapping, path) == f"{path}: mapping file is not UTF-8 text (byte 6: b'\\xff')"


def test_yaml_alias_bomb_is_refused_at_once(tmp_path):
    shipped = (REPO / "config" / "vehicles" / "crazyflie21.yaml").read_text()
    path = tmp_path / "bomb.yaml"
    path.write_text(shipped.replace("geometry: x", BOMB + "geometry: *h"))
    start = time.perf_counter()
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    assert time.perf_counter() - start < 1.0
    assert str(info.value) == f"{path}: vehicle config expands (through YAML aliases) to more than 100000 nodes"


def test_invalid_yaml_is_one_line_with_its_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\ngeometry: [x\n")
    assert refusal(ConfigError, load_vehicle, path) == f"{path}: vehicle config is not valid YAML at line 3: expected ',' or ']', but got '<stream end>'"


def rewrite_bag(source, target, edit):
    """Copy a bag message by message through ``edit(topic, index, msg)``, keeping its custom_data."""
    counts = {}
    with Reader(source) as reader:
        writer = Writer(target, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        connections = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=TYPESTORE) for c in reader.connections}
        for key, value in yaml.safe_load((source / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"].items():
            writer.set_custom_data(key, value)
        for connection, stamp, raw in reader.messages():
            index = counts[connection.topic] = counts.get(connection.topic, -1) + 1
            raw = edit(connection, index, raw)
            writer.write(connections[connection.id], stamp, raw)
        writer.close()
    return target


def test_undeserialisable_message_names_topic_and_index(tmp_path):
    good = write_bag(synthetic_log(n=20), tmp_path / "good")
    bag = rewrite_bag(good, tmp_path / "bad", lambda c, i, raw: raw[:12] + b"\xff\xff\xff\x7f" + raw[16:] if c.topic == "/quad/imu" and i == 3 else raw)
    assert refusal(BagError, load_flight, bag).startswith(f"{bag}: topic /quad/imu message 3: cannot deserialise (SerdeError: ")


def test_zero_norm_quaternion_in_a_bag_names_topic_and_message(tmp_path):
    good = write_bag(synthetic_log(n=20), tmp_path / "good")

    def zero_quaternion(connection, index, raw):
        if connection.topic != "/quad/mocap/odom" or index != 7:
            return raw
        msg = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
        q = msg.pose.pose.orientation
        q.x = q.y = q.z = q.w = 0.0
        return TYPESTORE.serialize_cdr(msg, connection.msgtype)

    bag = rewrite_bag(good, tmp_path / "zero", zero_quaternion)
    assert refusal(DataError, load_flight, bag) == f"{bag}: topic /quad/mocap/odom message 7 has an orientation quaternion of norm 0, not 1"


def test_bad_notes_json_and_bad_metadata_in_a_bag(tmp_path):
    bag = write_bag(synthetic_log(n=20), tmp_path / "bag")
    metadata = (bag / "metadata.yaml").read_text()
    (bag / "metadata.yaml").write_text(metadata.replace("""quad_modelling.notes: '{"seed": 0}'""", "quad_modelling.notes: '{bad'"))
    assert refusal(BagError, load_flight, bag) == f"{bag}: custom_data {NOTES_KEY} is not valid JSON (Expecting property name enclosed in double quotes at character 1)"
    deep = '{"a": ' + "[" * 50_000 + "]" * 50_000 + "}"
    (bag / "metadata.yaml").write_text(metadata.replace("""quad_modelling.notes: '{"seed": 0}'""", f"quad_modelling.notes: '{deep}'"))
    assert refusal(BagError, load_flight, bag) == f"{bag}: custom_data {NOTES_KEY} nests deeper than JSON can be read"
    (bag / "metadata.yaml").write_text("::: [\n")
    assert refusal(BagError, load_flight, bag) == (
        f"{bag}: not a readable rosbag2 bag: {bag / 'metadata.yaml'}: bag metadata is not valid YAML at line 2: "
        "expected the node content, but found '<stream end>'"
    )
    (bag / "metadata.yaml").write_text(metadata + BOMB)
    with pytest.raises(BagError, match="bag metadata expands .through YAML aliases. to more than 100000 nodes$"):
        load_flight(bag)


def test_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "flight.csv"
    os.mkfifo(fifo)
    assert refusal(DataError, load_flight, fifo) == f"{fifo}: is a FIFO, not a regular file; give the flight file as a file"


def test_unknown_vehicle_named_by_a_file_names_the_file(tmp_path):
    log = synthetic_log(vehicle="linkquad")
    log.meta.vehicle = "no_such_quad"
    write_matlog(log, tmp_path / "a.mat")
    message = refusal(ConfigError, load_flight, tmp_path / "a.mat")
    assert message.startswith(f"{tmp_path / 'a.mat'}: unknown vehicle 'no_such_quad'; shipped: ")
    assert message.endswith("; the flight (or its topic map's default_vehicle) names it: pass its vehicle file with --vehicle FILE.yaml (for a bag of a PX4 log, "
                            "the one `convert --vehicle-from-log` wrote)")


def test_ulog_corruption_notice_stays_off_stdout(tmp_path, capsys):
    source = REPO / "test" / "data" / "px4" / "sample_px4_events.ulg"
    path = tmp_path / "cut.ulg"
    path.write_bytes(source.read_bytes()[: source.stat().st_size // 100])
    with pytest.raises(DataError) as info:
        load_flight(path)
    assert capsys.readouterr().out == ""  # pyulog printed "File corruption detected ..." here
    assert str(info.value).startswith(f"{path}: missing PX4 topic(s) actuator_motors or actuator_outputs; ")


def test_text_file_as_model_is_not_a_zip_archive(tmp_path):
    path = tmp_path / "model.npz"
    path.write_text("not a model\n")
    assert refusal(ModelError, load_narx, path) == f"{path}: not a readable model file: not an .npz (zip) archive; expected a file written by quad-modelling train"


def test_model_array_header_declaring_7_pib_is_refused(tmp_path):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2**50,)})
    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("w_u.npy", header.getvalue() + bytes(8))
    assert refusal(ModelError, load_narx, path) == f"{path}: member w_u.npy declares a (1125899906842624,) float64 array (9007199254740992 bytes) but holds 8; corrupt model file"


def test_model_member_beyond_the_size_limit_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "model.npz"
    path.write_bytes(model_bytes(MODEL.header(), MODEL.arrays()))
    monkeypatch.setattr(model_files, "MAX_ARRAY_BYTES", 100)
    message = refusal(ModelError, load_narx, path)
    assert message.startswith(f"{path}: member header.npy inflates to ") and message.endswith(" bytes, more than the 100 a model array may have")


@pytest.mark.parametrize("key, value, message", [
    ("dt", "fast", "header field 'dt' is str 'fast', expected int or float"),
    ("dt", -0.01, "header field 'dt' must be a positive sample period [s], got -0.01"),
    ("training", 5, "header field 'training' is int '5', expected dict"),
])
def test_wrong_types_in_a_model_header(tmp_path, key, value, message):
    header = {**MODEL.header(), key: value}
    path = tmp_path / "model.npz"
    path.write_bytes(model_bytes(header, MODEL.arrays()))
    assert refusal(ModelError, load_narx, path) == f"{path}: {message}"
    json.dumps(header)  # the header itself is valid JSON: the refusal is about the types


@pytest.mark.parametrize("setting, value, message", [
    ("incremental", "no", "'no' is not true or false"),  # a non-empty string was read as true
    ("hidden", "10", "'10' is not a whole number"),
    ("hidden", True, "'True' is not a whole number"),
])
def test_a_model_setting_of_another_json_type_is_refused_not_converted(tmp_path, setting, value, message):
    header = MODEL.header()
    header["config"] = {**header["config"], setting: value}
    path = tmp_path / "model.npz"
    path.write_bytes(model_bytes(header, MODEL.arrays()))
    assert refusal(ModelError, load_narx, path) == f"{path}: incomplete model file (missing or invalid TypeError: {message})"


def test_a_model_file_holding_a_member_or_a_header_key_twice_or_non_real_arrays_is_refused(tmp_path):
    """numpy read one of two w_u members, json the last of two dt keys, a complex array with a ComplexWarning (two
    lines) and a structured one as numbers: each changed the predictions at exit 0."""
    good = model_bytes(MODEL.header(), MODEL.arrays())
    path = tmp_path / "model.npz"
    path.write_bytes(good)
    with zipfile.ZipFile(path, "a") as archive, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # zipfile's "Duplicate name"
        stream = io.BytesIO()
        np.save(stream, MODEL.arrays()["w_u"] * 2)
        archive.writestr("w_u.npy", stream.getvalue())
    assert refusal(ModelError, load_narx, path) == f"{path}: holds member w_u.npy twice; corrupt model file"
    text = json.dumps(MODEL.header())
    stream = io.BytesIO()
    np.savez(stream, header=np.array(text[:-1] + ', "dt": 0.02}'), **MODEL.arrays())
    path.write_bytes(stream.getvalue())
    assert refusal(ModelError, load_narx, path) == f"{path}: corrupt model header (ValueError: key 'dt' appears twice)"
    for array, dtype in ((MODEL.arrays()["w_u"].astype(complex), "complex128"),
                         (np.zeros(MODEL.arrays()["b_2"].shape, dtype=[("a", "<f8")]), "[('a', '<f8')]")):
        path.write_bytes(model_bytes(MODEL.header(), {**MODEL.arrays(), "w_u": array}))
        assert refusal(ModelError, load_narx, path) == f"{path}: member w_u.npy holds dtype {dtype}, not real numbers"


def test_a_vehicle_given_that_contradicts_the_one_a_flight_names_is_refused(tmp_path):
    """A simulated LinkQuad log read with --vehicle crazyflie21 had its pulse seconds taken as PWM (every constant
    fitted to a bound, exit 0): refused in one line, .mat and bag alike; the vehicle the flight names (or a file of
    it) is still taken."""
    from quad_modelling.io.bag_io import write_bag

    log = synthetic_log(vehicle="linkquad")
    write_matlog(log, tmp_path / "lq.mat")
    write_bag(log, tmp_path / "lq_bag")
    for path in (tmp_path / "lq.mat", tmp_path / "lq_bag"):
        message = refusal(DataError, load_flight, path, "crazyflie21")
        assert message == (f"{path}: the flight names vehicle 'linkquad', --vehicle gives 'crazyflie21': pass a vehicle file "
                           "of 'linkquad' (name: linkquad in the YAML, as identify writes it) or none")
        assert load_flight(path, "linkquad").meta.vehicle == "linkquad"


def test_position_of_1e30_m_is_refused(tmp_path):
    path = csv_with(tmp_path, 10, "py", "1e30")
    # NanoBench's y (east) is the internal NED frame's column 0 (north-east swapped, frames.py)
    assert refusal(DataError, load_flight, path) == (f"{path}: field pos_n column 0 (north) at sample 10 of 30 (t=0.090 s into the flight) is 1e+30, beyond ±1e+05 m "
                                                     "(no local frame is that large): wrong unit or corrupt data")
