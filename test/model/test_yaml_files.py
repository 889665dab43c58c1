"""read_yaml_mapping: every slip with an input YAML file is the caller's error, naming the file and the fix."""
import os
from pathlib import Path

import pytest

from dea_ros.errors import DeaRosError, ExperimentError, ParameterError, PlanningError, ProtocolError, SpecError
from dea_ros.identify.experiments import load_experiment_set
from dea_ros.identify.planning import first_fit_from_file
from dea_ros.identify.protocols import load_protocol
from dea_ros.model import MembraneParameters
from dea_ros.model.yaml_files import read_yaml_mapping
from dea_ros.study.spec import load_spec

FIX = "give a YAML path or a preset name"


def read(path):
    return read_yaml_mapping(path, ParameterError, "parameters file", fix=FIX, mapping="a mapping of field: value")


def test_a_mapping_is_returned_as_written(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("k1_Pa: 150000.0\nmembrane:\n  thickness_m: 5.0e-5\n")
    assert read(path) == {"k1_Pa": 150000.0, "membrane": {"thickness_m": 5.0e-5}}
    assert read(str(path)) == read(path)


def test_a_missing_file_names_it_and_the_fix(tmp_path):
    path = tmp_path / "nowhere" / "p.yaml"
    with pytest.raises(ParameterError) as err:
        read(path)
    assert str(err.value) == f"{path}: no such parameters file; {FIX}"


def test_a_directory_is_not_read(tmp_path):
    with pytest.raises(ParameterError, match=rf"^{tmp_path}: is a directory, not a parameters file; {FIX}$"):
        read(tmp_path)


def test_a_device_is_not_a_regular_file():
    if not Path("/dev/null").exists():
        pytest.skip("no /dev/null")
    with pytest.raises(ParameterError, match="^/dev/null: not a regular file"):
        read("/dev/null")


def test_a_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("k1_Pa: 1.5e5\nthickness_m: 5e-5\nprestretch: [1, 2\nmass_kg: 0.003\n")
    with pytest.raises(ParameterError) as err:
        read(path)
    message = str(err.value)
    assert message.startswith(f"{path}: not valid YAML (")
    assert "line 3" in message or "line 4" in message, message  # the open bracket's line or where it failed
    assert err.value.__cause__ is None  # the YAML error is in the message: no chained traceback


def test_a_tab_indentation_error_names_its_line(tmp_path):
    path = tmp_path / "tabs.yaml"
    path.write_text("membrane:\n  k1_Pa: 1\n\tthickness_m: 2\n")
    with pytest.raises(ParameterError, match=r"(?s)not valid YAML .*line 3"):
        read(path)


EMPTY = "the parameters file is empty; it should hold a mapping of field: value"


@pytest.mark.parametrize("content, problem", [
    (b"", EMPTY), (b"\n\n", EMPTY), (b"# only a comment\n", EMPTY), (b"---\n", EMPTY),
    (b"- 1\n- 2\n", "expected a mapping of field: value, got a list at the top level"),
    (b"3.5\n", "expected a mapping of field: value, got a float at the top level"),
    (b"just words\n", "expected a mapping of field: value, got a str at the top level"),
])
def test_an_empty_file_a_list_or_a_scalar_is_not_a_mapping(tmp_path, content, problem):
    path = tmp_path / "p.yaml"
    path.write_bytes(content)
    with pytest.raises(ParameterError) as err:
        read(path)
    assert str(err.value) == f"{path}: {problem}"


def test_non_utf8_bytes_are_binary_content_with_the_decode_error_as_cause(tmp_path):
    path = tmp_path / "binary.yaml"
    path.write_bytes(b"k1_Pa: 1\n" + bytes(range(128, 256)))
    with pytest.raises(ParameterError) as err:
        read(path)
    assert str(err.value).startswith(f"{path}: not a text file (binary content at byte 9); the parameters file")
    assert isinstance(err.value.__cause__, UnicodeDecodeError)  # the CLI names the option from it
    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes("name: Pr\u00fcfstand\n".encode("latin-1"))
    with pytest.raises(ParameterError, match="not a text file"):
        read(latin1)
    utf8 = tmp_path / "utf8.yaml"
    utf8.write_bytes("name: Pr\u00fcfstand\n".encode("utf-8"))
    assert read(utf8) == {"name": "Pr\u00fcfstand"}


def test_a_file_that_cannot_be_read_names_the_reason(tmp_path, monkeypatch):
    path = tmp_path / "locked.yaml"
    path.write_text("k1_Pa: 1\n")
    if os.geteuid() != 0:  # a real permission problem where the user is not root
        path.chmod(0)
    else:
        def denied(self):
            raise PermissionError(13, "Permission denied", str(self))
        monkeypatch.setattr(Path, "read_bytes", denied)
    try:
        with pytest.raises(ParameterError) as err:
            read(path)
    finally:
        path.chmod(0o644)
    assert str(err.value) == f"{path}: cannot read the parameters file (Permission denied); {FIX}"
    assert isinstance(err.value.__cause__, PermissionError)


def test_deep_nesting_is_left_to_the_caller(tmp_path):
    """RecursionError is not wrapped: the command line names it itself (as before the helper)."""
    path = tmp_path / "deep.yaml"
    path.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(RecursionError):
        read(path)


@pytest.mark.parametrize("loader, error_cls, name", [
    (MembraneParameters.from_yaml, ParameterError, "params.yaml"),
    (load_protocol, ProtocolError, "protocol.yaml"),
    (load_experiment_set, ExperimentError, "manifest.yaml"),
    (load_spec, SpecError, "spec.yaml"),
    (first_fit_from_file, PlanningError, "params.yaml"),
])
@pytest.mark.parametrize("content, message", [
    (b"- 1\n- 2\n", "expected a mapping"),
    (b"", "is empty"),
    (b"a: [1\n", "not valid YAML"),
    (bytes(range(256)), "not a text file"),
])
def test_each_loader_keeps_its_own_error_class(tmp_path, loader, error_cls, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(error_cls, match=message) as err:
        loader(path)
    assert isinstance(err.value, DeaRosError) and str(path) in str(err.value)
