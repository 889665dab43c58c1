r"""Message definitions (MCAP ``ros2msg`` schemas) and RIHS01 type hashes, without ROS sourced.

Lookup order for the ``.msg`` text of ``pkg/msg/Type``:

1. installed ROS share directories: ``<prefix>/share/<pkg>/msg/<Type>.msg`` for every prefix in
   ``AMENT_PREFIX_PATH`` (a sourced ROS 2), then ``sys.prefix`` (the PyPI ROS wheels install
   ``share/<pkg>/msg/*.msg`` into the virtualenv prefix);
2. ``extra_definitions`` given to :class:`MessageDefinitionStore`;
3. the vendored texts in :mod:`dea_ros.bag.vendored_messages` (Kilted copies of the rig's types).

The full schema text is built exactly like rosbag2's ``LocalMessageDefinitionSource::get_full_text``
(``rosbag2_cpp/src/rosbag2_cpp/message_definitions/local_message_definition_source.cpp``): the
root ``.msg`` text, then for each dependency (field types matched at line starts, sorted, each
type once, depth first) a line of 80 ``=``, a line ``MSG: <type as written in the field>`` (e.g.
``MSG: std_msgs/Header``) and that type's text, each block preceded by ``"\n"``.

Type hashes (``RIHS01_<sha256 hex>``, REP-2016) are read from the ``<Type>.json`` type description
that rosidl installs next to the ``.msg`` (``type_hashes[]``), only when the ``.msg`` itself came
from that installation. Vendored definitions carry no hash: the bag then stores an empty
``type_description_hash`` and no ``topic_type_hash`` channel metadata, which every reader accepts.
"""
from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path
from typing import Mapping, NamedTuple, Sequence

from ..errors import BagError
from .vendored_messages import VENDORED_MSG_TEXTS

__all__ = [
    "MessageDefinition",
    "MessageDefinitionStore",
    "default_search_prefixes",
    "normalize_type_name",
]

#: rosbag2's MSG_FIELD_TYPE_REGEX: a field type at the start of a line (array suffix allowed).
_MSG_FIELD_TYPE_RE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
#: rosbag2's PRIMITIVE_TYPES (+ ``wstring``, which rosbag2 would wrongly treat as a message type).
_PRIMITIVE_TYPES = frozenset(
    {
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
        "int32", "uint32", "int64", "uint64", "string", "wstring",
    }
)
_SEPARATOR = "=" * 80 + "\n"
_ROS_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE_RE = re.compile(rf"^({_ROS_NAME})/(?:({_ROS_NAME})/)?({_ROS_NAME})$")
#: Safety limit mirroring ROSBAG2_CPP_LOCAL_MESSAGE_DEFINITION_SOURCE_MAX_RECURSION_DEPTH.
_MAX_DEPTH = 50


class MessageDefinition(NamedTuple):
    """Everything a bag needs about one message type."""

    type_name: str  #: canonical ``pkg/msg/Type``
    encoding: str  #: MCAP schema encoding, always ``ros2msg`` here
    text: str  #: full concatenated definition (root + dependencies)
    type_hash: str  #: ``RIHS01_...`` or ``""`` when unknown
    source: str  #: path of the root ``.msg`` or ``"vendored"`` / ``"extra_definitions"``


def normalize_type_name(type_name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` -> ``pkg/msg/Type``; raise ``BagError`` if malformed."""
    match = _TYPE_RE.match(type_name or "")
    if match is None:
        raise BagError(
            f"message type {type_name!r} is not a ROS 2 type name; expected 'pkg/msg/Type' "
            "(e.g. 'std_msgs/msg/Float64')"
        )
    package, namespace, name = match.groups()
    return f"{package}/{namespace or 'msg'}/{name}"


def default_search_prefixes() -> list[Path]:
    """Install prefixes searched for ``share/<pkg>/msg``: ``AMENT_PREFIX_PATH`` then ``sys.prefix``."""
    prefixes: list[Path] = []
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry:
            prefixes.append(Path(entry))
    prefixes.append(Path(sys.prefix))
    unique: list[Path] = []
    for prefix in prefixes:
        if prefix not in unique and (prefix / "share").is_dir():
            unique.append(prefix)
    return unique


class MessageDefinitionStore:
    """Resolves ``.msg`` texts, full schema texts and type hashes; caches per instance.

    * ``search_prefixes``: install prefixes to search (default :func:`default_search_prefixes`);
      pass ``[]`` to use only extra/vendored definitions.
    * ``extra_definitions``: ``{"pkg/msg/Type": msg_text}`` for types with no installed or
      vendored definition (e.g. custom messages when ROS is not sourced).
    * ``use_vendored``: fall back to the vendored Kilted texts.
    """

    def __init__(
        self,
        search_prefixes: Sequence[str | Path] | None = None,
        extra_definitions: Mapping[str, str] | None = None,
        use_vendored: bool = True,
    ) -> None:
        if search_prefixes is None:
            self._prefixes = default_search_prefixes()
        else:
            self._prefixes = [Path(p) for p in search_prefixes]
        self._extra = {normalize_type_name(k): v for k, v in (extra_definitions or {}).items()}
        self._use_vendored = use_vendored
        self._texts: dict[str, tuple[str, str]] = {}
        self._full: dict[str, MessageDefinition] = {}

    @property
    def search_prefixes(self) -> list[Path]:
        """The install prefixes searched, in order."""
        return list(self._prefixes)

    def _installed_msg_path(self, canonical: str) -> Path | None:
        package, namespace, name = canonical.split("/")
        for prefix in self._prefixes:
            candidate = prefix / "share" / package / namespace / f"{name}.msg"
            if candidate.is_file():
                return candidate
        return None

    def msg_text(self, type_name: str) -> tuple[str, str]:
        """``(text of the single .msg file, source)`` for ``type_name``; ``BagError`` if unknown."""
        canonical = normalize_type_name(type_name)
        cached = self._texts.get(canonical)
        if cached is not None:
            return cached
        path = self._installed_msg_path(canonical)
        if path is not None:
            try:
                result = (path.read_text(encoding="utf-8"), str(path))
            except OSError as exc:
                raise BagError(f"cannot read message definition {path}: {exc}") from exc
        elif canonical in self._extra:
            result = (self._extra[canonical], "extra_definitions")
        elif self._use_vendored and canonical in VENDORED_MSG_TEXTS:
            result = (VENDORED_MSG_TEXTS[canonical], "vendored")
        else:
            searched = ", ".join(str(p / "share") for p in self._prefixes) or "(no prefixes)"
            raise BagError(
                f"no .msg definition for {canonical}: not found under {searched}, not in "
                "extra_definitions and not vendored; source the ROS 2 installation providing it "
                "or pass extra_definitions={type: msg_text}"
            )
        self._texts[canonical] = result
        return result

    def type_hash(self, type_name: str) -> str:
        """``RIHS01_...`` from the installed ``<Type>.json`` next to the ``.msg``, else ``""``."""
        canonical = normalize_type_name(type_name)
        _, source = self.msg_text(canonical)
        if source in ("vendored", "extra_definitions"):
            return ""
        json_path = Path(source).with_suffix(".json")
        try:
            description = json.loads(json_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return ""
        for entry in description.get("type_hashes", []) if isinstance(description, dict) else []:
            if isinstance(entry, dict) and entry.get("type_name") == canonical:
                hash_string = entry.get("hash_string", "")
                if isinstance(hash_string, str) and hash_string.startswith("RIHS01_"):
                    return hash_string
        return ""

    def full_definition(self, type_name: str) -> MessageDefinition:
        """Root text + dependencies exactly as rosbag2 writes the MCAP schema."""
        canonical = normalize_type_name(type_name)
        cached = self._full.get(canonical)
        if cached is not None:
            return cached
        seen: set[str] = set()

        def append_recursive(name: str, depth: int) -> str:
            if depth <= 0:
                raise BagError(f"message definition of {canonical} nests deeper than {_MAX_DEPTH} levels")
            text, _ = self.msg_text(name)
            package = normalize_type_name(name).split("/")[0]
            result = text
            for dependency in _parse_dependencies(text, package):
                if dependency not in seen:
                    seen.add(dependency)
                    result += "\n" + _SEPARATOR + f"MSG: {dependency}\n"
                    result += append_recursive(dependency, depth - 1)
            return result

        text = append_recursive(canonical, _MAX_DEPTH)
        _, source = self.msg_text(canonical)
        definition = MessageDefinition(canonical, "ros2msg", text, self.type_hash(canonical), source)
        self._full[canonical] = definition
        return definition


def _parse_dependencies(text: str, package_context: str) -> list[str]:
    """Non-primitive field types of a ``.msg`` text, sorted (rosbag2 uses a ``std::set``)."""
    dependencies: set[str] = set()
    for match in _MSG_FIELD_TYPE_RE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        dependencies.add(field_type if "/" in field_type else f"{package_context}/{field_type}")
    return sorted(dependencies)
