"""Reading an input YAML file whose top level is a mapping, every way of failing named.

Parameters files, protocols, experiment manifests, study specs and identified params.yaml files
are all such files. :func:`read_yaml_mapping` reads one and turns each slip a user can make with it
(a missing file, a folder, a file that cannot be read, binary content, a YAML syntax error, an
empty file, a list or a scalar at the top) into the caller's error class of the
:class:`~dea_ros.errors.DeaRosError` family, with a message naming the file, what is wrong and the
fix; the command line prints it and exits with code 2.

A file that cannot be read (permissions, binary content) raises the error ``from`` the
``OSError`` or ``UnicodeDecodeError``, so a caller that knows the option the path came from can
name it. A YAML nested too deeply to parse raises :class:`RecursionError` as before: the command
line names that one itself.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import yaml

__all__ = ["read_yaml_mapping"]


def read_yaml_mapping(path, error_cls: type[Exception], what: str, *, fix: str = "",
                      mapping: str = "a mapping of key: value") -> Mapping[str, Any]:
    """The top-level mapping of the YAML file ``path``; ``error_cls`` for every way it is not one.

    ``what`` names the file in the messages (``"parameters file"``: "no such parameters file"),
    ``fix`` is appended to the messages about the path (``"give a YAML path or a preset name"``),
    ``mapping`` says what the top level should hold (``"a mapping of field: value"``).
    """
    path = Path(path)
    then = f"; {fix}" if fix else ""
    if not path.is_file():
        if path.is_dir():
            raise error_cls(f"{path}: is a directory, not a {what}{then}")
        if path.exists():
            raise error_cls(f"{path}: not a regular file (a device or pipe?), not a {what}{then}")
        raise error_cls(f"{path}: no such {what}{then}")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error_cls(f"{path}: not a text file (binary content at byte {exc.start}); the {what} "
                        "is UTF-8 YAML text") from exc
    except OSError as exc:
        raise error_cls(f"{path}: cannot read the {what} ({exc.strerror or exc}){then}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error_cls(f"{path}: not valid YAML ({exc})") from None
    if data is None:
        raise error_cls(f"{path}: the {what} is empty; it should hold {mapping}")
    if not isinstance(data, Mapping):
        raise error_cls(f"{path}: expected {mapping}, got a {type(data).__name__} at the top level")
    return data
