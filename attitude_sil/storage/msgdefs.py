"""ROS 2 message definitions for MCAP schemas, built the way rosbag2 builds them.

An MCAP file of the ``ros2`` profile stores, for every message type, a schema
of encoding ``ros2msg`` whose data is the type's ``.msg`` text followed by the
text of every type it depends on, recursively.  rosbag2 (Jazzy,
``rosbag2_cpp::LocalMessageDefinitionSource``) concatenates them like this::

    <text of pkg/msg/Root.msg>
    ================================================================================
    MSG: other_pkg/Dependency
    <text of other_pkg/msg/Dependency.msg>
    ...

Dependencies of each definition are visited in sorted order, depth first, each
one written once; a dependency is named as it appears in the referring file
(``std_msgs/Header``) or, when written without a package, with the package of
the referring file (``Vector3`` in geometry_msgs becomes
``geometry_msgs/Vector3``).  The ``MSG:`` lines therefore carry no ``/msg/``,
while the schema name itself is the full ``pkg/msg/Name``.  Both
mcap-ros2-support and rosbags parse this format.

The ``.msg`` files are looked up through ament_index_python and, when the
ament index is not set up (a plain virtualenv with ROS wheels), under
``<sys.prefix>/share/<pkg>/msg/``.  A type the project writes whose package
has no wheel on PyPI, ``tf2_msgs/msg/TFMessage`` (the bags' and the live
view's ``/tf``), is bundled here: its standard ``.msg`` text and RIHS01 hash
(:data:`BUNDLED_MESSAGES`), used where no installed file is found, so a bag
carries the definition ``ros2 bag play`` on a full install republishes.
This module does not import rclpy.
"""

from __future__ import annotations

import functools
import json
import re
import sys
from pathlib import Path

__all__ = [
    'BUNDLED_MESSAGES',
    'SEPARATOR',
    'message_definition',
    'normalize_type_name',
    'type_description_hash',
]

#: The line rosbag2 puts between two concatenated definitions.
SEPARATOR = '=' * 80

#: Types without a wheel on PyPI: ``pkg/msg/Name`` -> (the ``.msg`` text of
#: ROS 2 Jazzy, its RIHS01 type hash). tf2_msgs (ros2/geometry2) defines
#: TFMessage as this one line; the hash is the one rosidl generates for it.
BUNDLED_MESSAGES: dict[str, tuple[str, str]] = {
    'tf2_msgs/msg/TFMessage': (
        'geometry_msgs/TransformStamped[] transforms\n',
        'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087',
    ),
}

# Primitive .msg types: the ones rosbag2 knows plus wstring, which rosbag2
# would otherwise mistake for a message type of the referring package.
_PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
    'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring',
})

_NAME = r'[A-Za-z][A-Za-z0-9_]*'
_TYPE_NAME_RE = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')
# A field type with an optional array suffix ([], [3], [<=3]); the string
# bound of string<=N is removed before this is applied.
_ARRAY_SUFFIX_RE = re.compile(r'\[[^\]]*\]$')
# rosbag2 gives up past this depth; so do we (it only happens for cycles).
_MAX_DEPTH = 50


def normalize_type_name(type_name: str) -> str:
    """Return the full ``pkg/msg/Name`` form of a message type name.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Name`` or the short ``pkg/Name`` form.

    Returns
    -------
    str
        ``pkg/<namespace>/Name``; the namespace is ``msg`` when omitted.

    Raises
    ------
    ValueError
        If the name is not a valid ROS 2 interface type name.
    """
    package, namespace, name = _split_type_name(type_name)
    return f'{package}/{namespace}/{name}'


def message_definition(type_name: str) -> str:
    """Return the rosbag2-style concatenated ``.msg`` definition of a type.

    Parameters
    ----------
    type_name : str
        Message type such as ``geometry_msgs/msg/Vector3Stamped`` (the short
        ``geometry_msgs/Vector3Stamped`` is accepted too).

    Returns
    -------
    str
        The type's ``.msg`` text followed by each dependency, recursively,
        preceded by a line of 80 ``=`` and a ``MSG: pkg/Name`` line; exactly
        what rosbag2 stores as the data of an MCAP ``ros2msg`` schema.

    Raises
    ------
    ValueError
        If the name is invalid or the ``.msg`` file of the type or of one of
        its dependencies cannot be found.
    """
    return _message_definition(normalize_type_name(type_name))


def type_description_hash(type_name: str) -> str:
    """Return the RIHS01 type hash of a message type, or ``''`` if unknown.

    The hash is the one rosidl generated for the type (read from the
    ``<Name>.json`` type description installed next to the ``.msg`` file);
    rosbag2 records it as ``type_description_hash`` of a topic.

    Parameters
    ----------
    type_name : str
        Message type such as ``geometry_msgs/msg/Vector3Stamped``.

    Returns
    -------
    str
        A string ``RIHS01_<64 hex digits>``, or ``''`` when no type
        description is installed for the type.

    Raises
    ------
    ValueError
        If the name is not a valid ROS 2 interface type name.
    """
    return _type_description_hash(normalize_type_name(type_name))


def _split_type_name(type_name: str) -> tuple[str, str, str]:
    match = _TYPE_NAME_RE.match(type_name) if isinstance(type_name, str) else None
    if match is None:
        raise ValueError(
            f'invalid message type name {type_name!r}: expected pkg/msg/Name'
        )
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def _share_directories(package: str) -> list[Path]:
    """Candidate share directories of a package, most authoritative first."""
    candidates: list[Path] = []
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        pass
    else:
        try:
            candidates.append(Path(get_package_share_directory(package)))
        except (LookupError, OSError, ValueError):
            # Not in the ament index, or AMENT_PREFIX_PATH is not set.
            pass
    fallback = Path(sys.prefix) / 'share' / package
    if fallback not in candidates:
        candidates.append(fallback)
    return candidates


def _find_interface_file(package: str, namespace: str, name: str,
                         suffix: str) -> tuple[Path | None, list[Path]]:
    """Find ``<share>/<namespace>/<name><suffix>``; also return where it looked."""
    looked: list[Path] = []
    for share in _share_directories(package):
        path = share / namespace / f'{name}{suffix}'
        looked.append(path)
        if path.is_file():
            return path, looked
    return None, looked


@functools.cache
def _load_spec(package: str, namespace: str, name: str) -> tuple[str, tuple[str, ...]] | None:
    """Text and sorted dependency names of one ``.msg`` file, or None if absent."""
    path, _ = _find_interface_file(package, namespace, name, '.msg')
    if path is None:
        bundled = BUNDLED_MESSAGES.get(f'{package}/{namespace}/{name}')
        if bundled is None:
            return None
        text = bundled[0]
    else:
        text = path.read_text(encoding='utf-8')
    return text, tuple(sorted(_parse_dependencies(text, package)))


def _parse_dependencies(text: str, package: str) -> set[str]:
    """Names of the non-primitive field types used in a ``.msg`` text."""
    dependencies: set[str] = set()
    for raw_line in text.splitlines():
        line = raw_line.strip()
        if not line or line.startswith('#'):
            continue
        parts = line.split(None, 1)
        if len(parts) < 2:
            continue  # not a field or constant line
        field_type = _ARRAY_SUFFIX_RE.sub('', parts[0])
        field_type = field_type.split('<=', 1)[0]  # bounded string<=N
        if field_type in _PRIMITIVE_TYPES:
            continue
        if '/' not in field_type:
            field_type = f'{package}/{field_type}'
        dependencies.add(field_type)
    return dependencies


@functools.cache
def _message_definition(full_name: str) -> str:
    seen: set[str] = set()

    def append_recursive(type_name: str, depth: int) -> str:
        if depth <= 0:
            raise ValueError(
                f'message definition of {full_name!r} nests deeper than '
                f'{_MAX_DEPTH} levels (recursive type?)'
            )
        package, namespace, name = _split_type_name(type_name)
        spec = _load_spec(package, namespace, name)
        if spec is None:
            _, looked = _find_interface_file(package, namespace, name, '.msg')
            where = ', '.join(str(p) for p in looked)
            if type_name == full_name:
                raise ValueError(
                    f'no message definition found for {full_name!r} (looked for {where})'
                )
            raise ValueError(
                f'incomplete message definition for {full_name!r}: dependency '
                f'{type_name!r} not found (looked for {where})'
            )
        text, dependencies = spec
        parts = [text]
        for dependency in dependencies:
            if dependency in seen:
                continue
            seen.add(dependency)
            parts.append(f'\n{SEPARATOR}\nMSG: {dependency}\n')
            parts.append(append_recursive(dependency, depth - 1))
        return ''.join(parts)

    return append_recursive(full_name, _MAX_DEPTH)


@functools.cache
def _type_description_hash(full_name: str) -> str:
    package, namespace, name = _split_type_name(full_name)
    path, _ = _find_interface_file(package, namespace, name, '.json')
    if path is None:
        return BUNDLED_MESSAGES.get(full_name, ('', ''))[1]
    try:
        description = json.loads(path.read_text(encoding='utf-8'))
        for entry in description.get('type_hashes', []):
            if entry.get('type_name') == full_name:
                return str(entry.get('hash_string', ''))
    except (OSError, ValueError, AttributeError, TypeError):
        return ''
    return ''
