"""Damaged EDS and configuration files: one ``InputError`` line naming the file, never a crash.

The loading functions are the ones ``cheope run``/``bus-load`` (``check_device_descriptions``,
``load_config``) and ``cheope sim`` (``device_pdos_from_file``) call; hypothesis damages the
shipped files (truncations, junk bytes, other encodings, duplicated sections) and every outcome
must be a loaded file or that one line. The command line end to end is in
tests/integration/test_bad_files_cli.py.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.config import DEFAULT_CONFIG, ConfigError, load_config
from controller.errors import InputError
from controller.node_plan import node_setup_plan
from drivers.node_setup import DRIVE_EDS, SENSOR_EDS, check_device_descriptions
from drivers.pdo_mapping import DeviceDescriptionError, PdoDirection, load_device_description
from sim_backend.device_pdos import device_pdos_from_file

DRIVE_BYTES = DRIVE_EDS.read_bytes()
SENSOR_BYTES = SENSOR_EDS.read_bytes()
CONFIG_BYTES = DEFAULT_CONFIG.read_bytes()
FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# What a user might have saved a file as: each fails as UTF-8 once a non-ASCII character is in it.
OTHER_ENCODINGS = ("utf-16", "utf-16-le", "utf-16-be", "utf-32", "latin-1", "cp1252", "shift_jis")


def _sections(data: bytes) -> list[bytes]:
    """Each ``[section]`` of an INI/TOML text with its lines, up to the next header."""
    starts = [m.start() for m in re.finditer(rb"^\[", data, flags=re.MULTILINE)]
    return [data[a:b] for a, b in zip(starts, [*starts[1:], len(data)], strict=True)]


def _section(data: bytes, header: bytes) -> bytes:
    return next(s for s in _sections(data) if s.startswith(header))


def _one_line_naming(err: BaseException, path: Path) -> str:
    message = str(err)
    assert "\n" not in message, message
    assert str(path) in message, message
    return message


def _load_eds_everywhere(path: Path, sensor: bool = False) -> None:
    """What the controller (before opening a bus) and the simulator build from the file."""
    plan = node_setup_plan(load_config(overrides={"sensor.enabled": sensor}))
    plan = replace(plan, sensor_eds=path) if sensor else replace(plan, drive_eds=path)
    for load in (
        lambda: check_device_descriptions(plan),
        lambda: device_pdos_from_file(path, 16 if sensor else 1),
    ):
        try:
            load()
        except DeviceDescriptionError as err:
            _one_line_naming(err, path)


def _write(directory: str, name: str, data: bytes) -> Path:
    path = Path(directory) / name
    path.write_bytes(data)
    return path


# -- EDS files: each damage of the issue, by hand --------------------------------------------


def _without_headers(data: bytes) -> bytes:
    return re.sub(rb"^\[.*\]\r?\n", b"", data, flags=re.MULTILINE)


@pytest.mark.parametrize(
    "damage,expected",
    [
        (
            lambda d: d[: d.index(b"SubNumber") + 4],
            r"line \d+ is not KEY=VALUE: 'SubN'",
        ),  # cut in the middle of a line
        (lambda d: d[: d.index(b"[1000]")], "describes no objects"),  # cut before the first object
        (_without_headers, r"line \d+ comes before any \[section\] header"),
        (lambda d: d + b"\n" + _section(d, b"[1000]"), r"section \[1000\] appears twice"),
        (lambda d: b"", "is empty"),
        (lambda d: b"\n  \n", "is empty"),
        (lambda d: b"[FileInfo]\nFileName=x.eds\n", "describes no objects"),
        (lambda d: d.decode().encode("utf-16"), "is UTF-16 text"),
        (
            lambda d: d.replace(b"linear", "lin\u00e9ar".encode("latin-1"), 1),
            r"not UTF-8 text: byte 0xE9 at line 1",
        ),
        (lambda d: d[:100] + b"\x00\x01\x02" + d[100:], "control character 0x00 at line"),
        (
            lambda d: d.replace(b"ParameterName=Device type", b"Name=Device type", 1),
            "is not a valid device description: No option 'ParameterName' in section: '1000'",
        ),
    ],
)
def test_each_damaged_eds_is_one_line_naming_file_and_fault(tmp_path, damage, expected):
    path = _write(str(tmp_path), "drive.eds", damage(DRIVE_BYTES))
    with pytest.raises(DeviceDescriptionError) as err:
        load_device_description(path, 1)
    assert re.search(expected, _one_line_naming(err.value, path)), str(err.value)


def test_an_eds_path_that_is_a_directory_says_so_not_that_it_does_not_exist(tmp_path):
    (tmp_path / "drive.eds").mkdir()
    with pytest.raises(DeviceDescriptionError, match=re.escape("drive.eds is a directory, not a file")):
        load_device_description(tmp_path / "drive.eds", 1)
    with pytest.raises(DeviceDescriptionError, match=re.escape("nothing.eds does not exist")):
        load_device_description(tmp_path / "nothing.eds", 1)


def test_an_eds_without_the_pdos_the_project_needs_is_refused_naming_the_file(tmp_path):
    # parses, has objects, but TPDO1's mapping 0x1A00 is gone: the set-up could not build its codec
    kept = [s for s in _sections(DRIVE_BYTES) if not s.startswith(b"[1A00")]
    path = _write(str(tmp_path), "drive.eds", DRIVE_BYTES[: DRIVE_BYTES.index(b"[")] + b"".join(kept))
    plan = replace(node_setup_plan(load_config(overrides={"sensor.enabled": False})), drive_eds=path)
    with pytest.raises(DeviceDescriptionError) as err:
        check_device_descriptions(plan)
    assert "node 1 TPDO1" in _one_line_naming(err.value, path)


def test_a_pdo_mapping_declared_as_a_variable_is_refused_by_the_controller_and_not_a_crash_of_the_simulator(
    tmp_path,
):
    mapping = b"".join(s for s in _sections(DRIVE_BYTES) if s.startswith(b"[1A00"))
    as_variable = (
        b"[1A00]\nParameterName=TPDO1 mapping\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\n"
        b"DefaultValue=0\nPDOMapping=0\n\n"
    )
    path = _write(str(tmp_path), "drive.eds", DRIVE_BYTES.replace(mapping, as_variable))
    assert device_pdos_from_file(path, 1).pdo(PdoDirection.TRANSMIT, 1).config.objects == ()
    # the EDS's default TPDO mapping (the shipped configuration names its own objects)
    cfg = load_config(overrides={"sensor.enabled": False, "actuators.tpdo_objects": []})
    plan = replace(node_setup_plan(cfg), drive_eds=path)
    with pytest.raises(DeviceDescriptionError, match="TPDO mapping empty"):
        check_device_descriptions(plan)


def test_the_shipped_files_load_without_a_word(caplog):
    plan = node_setup_plan(load_config())
    check_device_descriptions(plan)
    assert len(load_device_description(DRIVE_EDS, 1)) > 20
    assert not caplog.records


def test_a_warning_of_canopen_about_a_file_that_loads_names_the_file(tmp_path, caplog):
    info = _sections(DRIVE_BYTES)[1]
    assert info.startswith(b"[DeviceInfo]")
    path = _write(str(tmp_path), "drive.eds", DRIVE_BYTES.replace(info, b""))
    load_device_description(path, 1)
    assert any(str(path) in r.getMessage() and "DeviceInfo" in r.getMessage() for r in caplog.records)


def test_the_command_line_keeps_canopens_warnings_about_a_file(tmp_path, caplog, capsys):
    """cheope's command line quiets canopen's SDO client only: run in this process before the load
    (as the suite's order did on CI), a command left the EDS reader's warning unsaid."""
    from controller.cli import main

    assert main(["bus-load"]) == 0
    capsys.readouterr()
    info = _sections(DRIVE_BYTES)[1]
    path = _write(str(tmp_path), "drive.eds", DRIVE_BYTES.replace(info, b""))
    load_device_description(path, 1)
    assert any(str(path) in r.getMessage() and "DeviceInfo" in r.getMessage() for r in caplog.records)


# -- EDS files: fuzzed ---------------------------------------------------------------------


@FUZZ
@given(st.sampled_from([(DRIVE_BYTES, False), (SENSOR_BYTES, True)]), st.data())
def test_a_truncated_eds_loads_or_is_one_line(shipped, data):
    content, sensor = shipped
    cut = data.draw(st.integers(0, len(content) - 1))
    with tempfile.TemporaryDirectory() as d:
        _load_eds_everywhere(_write(d, "device.eds", content[:cut]), sensor)


@FUZZ
@given(st.integers(0, len(DRIVE_BYTES)), st.binary(min_size=1, max_size=64))
def test_junk_bytes_in_an_eds_load_or_are_one_line(offset, junk):
    with tempfile.TemporaryDirectory() as d:
        _load_eds_everywhere(_write(d, "drive.eds", DRIVE_BYTES[:offset] + junk + DRIVE_BYTES[offset:]))


@FUZZ
@given(st.sampled_from(_sections(DRIVE_BYTES)), st.integers(0, 1))
def test_a_duplicated_eds_section_is_refused_naming_it(section, where):
    name = section[1 : section.index(b"]")].decode()
    at = DRIVE_BYTES.index(section) if where == 0 else len(DRIVE_BYTES)
    with tempfile.TemporaryDirectory() as d:
        path = _write(d, "drive.eds", DRIVE_BYTES[:at] + section + b"\n" + DRIVE_BYTES[at:])
        with pytest.raises(DeviceDescriptionError) as err:
            load_device_description(path, 1)
        assert f"section [{name}] appears twice" in _one_line_naming(err.value, path)


@FUZZ
@given(st.sampled_from(OTHER_ENCODINGS), st.sampled_from(["\u00b5m", "\u00e9", "\u2126", "\u00b0C"]))
def test_an_eds_in_another_encoding_is_refused_naming_the_encoding_problem(encoding, word):
    text = DRIVE_BYTES.decode().replace("linear drive", f"linear drive {word}", 1)
    try:
        encoded = text.encode(encoding)
    except UnicodeEncodeError:
        return  # this encoding cannot write the word: nothing a user could have saved
    with tempfile.TemporaryDirectory() as d:
        path = _write(d, "drive.eds", encoded)
        with pytest.raises(DeviceDescriptionError) as err:
            load_device_description(path, 1)
    assert re.search("UTF-16 text|not UTF-8 text|control character 0x00", _one_line_naming(err.value, path))


# -- configuration files --------------------------------------------------------------------


def _load_config_or_one_line(path: Path) -> None:
    try:
        load_config(path)
    except InputError as err:  # ConfigError, and the robots' and tasks' own checks
        assert "\n" not in str(err), str(err)


@pytest.mark.parametrize(
    "content,expected",
    [
        (CONFIG_BYTES.decode().encode("utf-16"), "is UTF-16 text"),
        (CONFIG_BYTES.replace(b"Cheope", "Ch\u00e9ope".encode("latin-1"), 1), "is not UTF-8 text: byte 0xE9"),
        (b"", "is empty"),
        (b"\x00\x00\x01", "is empty|control character 0x00"),
        (CONFIG_BYTES + b"\n[loop]\nrate_hz = 400\n", r"is not valid TOML: Cannot declare \('loop',\) twice"),
        (CONFIG_BYTES[: CONFIG_BYTES.index(b"\n[loop]") + 4], "is not valid TOML"),
        (b"a = " + b"[" * 5000 + b"]" * 5000, "nests arrays or tables too deeply|is not valid TOML"),
    ],
)
def test_each_damaged_configuration_is_one_line_naming_the_file(tmp_path, content, expected):
    path = _write(str(tmp_path), "robot.toml", content)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert re.search(expected, _one_line_naming(err.value, path)), str(err.value)


@pytest.mark.parametrize("kind", ["{ a = 1 }", "[1, 2]", "3"])
@pytest.mark.parametrize("group", ["robot", "task"])
def test_a_kind_that_is_not_a_name_is_one_line(tmp_path, group, kind):
    path = _write(str(tmp_path), "robot.toml", f"[{group}]\nkind = {kind}\n".encode())
    with pytest.raises(ConfigError, match=rf"{group}.kind = .*: must be one of"):
        load_config(path)


def test_a_configuration_path_that_is_a_directory_says_so(tmp_path):
    with pytest.raises(ConfigError, match=re.escape("robot.toml is a directory, not a file")):
        (tmp_path / "robot.toml").mkdir()
        load_config(tmp_path / "robot.toml")


@FUZZ
@given(st.data())
def test_a_truncated_configuration_loads_or_is_one_line(data):
    cut = data.draw(st.integers(0, len(CONFIG_BYTES) - 1))
    with tempfile.TemporaryDirectory() as d:
        _load_config_or_one_line(_write(d, "robot.toml", CONFIG_BYTES[:cut]))


@FUZZ
@given(st.integers(0, len(CONFIG_BYTES)), st.binary(min_size=1, max_size=32))
def test_junk_bytes_in_a_configuration_load_or_are_one_line(offset, junk):
    with tempfile.TemporaryDirectory() as d:
        _load_config_or_one_line(
            _write(d, "robot.toml", CONFIG_BYTES[:offset] + junk + CONFIG_BYTES[offset:])
        )


@FUZZ
@given(st.sampled_from([s for s in _sections(CONFIG_BYTES) if s.strip()]))
def test_a_duplicated_configuration_table_is_refused(section):
    with tempfile.TemporaryDirectory() as d:
        path = _write(d, "robot.toml", CONFIG_BYTES + b"\n" + section)
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert "is not valid TOML" in _one_line_naming(err.value, path)


@FUZZ
@given(st.sampled_from(OTHER_ENCODINGS))
def test_a_configuration_in_another_encoding_is_refused(encoding):
    text = CONFIG_BYTES.decode().replace("# ", "# \u00b0 ", 1)
    try:
        encoded = text.encode(encoding)
    except UnicodeEncodeError:
        return
    with tempfile.TemporaryDirectory() as d:
        path = _write(d, "robot.toml", encoded)
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert re.search(
            "UTF-16 text|not UTF-8 text|control character 0x00", _one_line_naming(err.value, path)
        )
