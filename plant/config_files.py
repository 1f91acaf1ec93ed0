"""Reading the YAML files a user gives the command line (scenarios, sweeps), strictly.

``load_mapping(path)`` returns the file's top-level mapping or raises ``ConfigFileError`` with
one sentence that names the file and the problem: a missing file, a directory, a file too large
or binary to be a configuration, an empty file, a YAML syntax error (with its line and column,
and a hint when a tab indents), a key given twice in one mapping, nesting deeper than the
parser's stack, aliases that expand into too many nodes (an "alias bomb": a few lines that
expand into billions of nodes), or a top level that is not a mapping.
Plain ``yaml.safe_load`` keeps the last of two duplicate keys silently and expands any alias.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from yaml.constructor import ConstructorError

#: Largest configuration file read, bytes: a scenario or sweep is a few kB (our choice).
MAX_FILE_BYTES = 1_000_000
#: Most YAML nodes in a file once its aliases (``*name``) are expanded: a scenario has a few
#: hundred; a nine-level "billion laughs" bomb has 9**9 (our choice).
MAX_NODES = 100_000
#: Deepest nesting of mappings and lists: a scenario has five levels (our choice).
MAX_DEPTH = 50


class ConfigFileError(ValueError):
    """A configuration file that cannot be read as a YAML mapping; the message says why."""


class _StrictLoader(yaml.SafeLoader):
    """``SafeLoader`` that rejects duplicate keys."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
            except TypeError:  # an unhashable key: the base class reports it
                break
            if duplicate:
                raise ConstructorError(
                    "while constructing a mapping", node.start_mark,
                    f"duplicate key {key!r}", key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _expanded_size(node: yaml.Node, memo: dict[int, int], depth: int = 0) -> int:
    """Number of nodes under ``node`` with every alias expanded (an alias shares its anchor's
    node object, so ``memo`` keeps this linear in the file's size). Raises ``RecursionError``
    below ``MAX_DEPTH`` levels, as the parser does when it runs out of stack."""
    if depth > MAX_DEPTH:
        raise RecursionError(f"more than {MAX_DEPTH} levels")
    key = id(node)
    if key not in memo:
        if isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        elif isinstance(node, yaml.SequenceNode):
            children = node.value
        else:
            children = []
        memo[key] = 1 + sum(_expanded_size(c, memo, depth + 1) for c in children)
    return memo[key]


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One line from a PyYAML error: the problem, where it is (1-based line and column), and a
    hint for tabs."""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    context = getattr(exc, "context", None)
    if context and problem.startswith("but "):  # "expected X, but found Y" is split in two
        problem = f"{context}, {problem}"
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    hint = "; indent with spaces, YAML does not allow tabs" if "\\t" in problem else ""
    return f"{problem}{where}{hint}"


def load_mapping(path: str | Path) -> dict:
    """The top-level mapping of the YAML file ``path``.

    Raises
    ------
    ConfigFileError
        If the file is missing, not a regular file, larger than ``MAX_FILE_BYTES``, binary,
        empty, not valid YAML, has duplicate keys, nests deeper than ``MAX_DEPTH`` levels,
        expands into more than ``MAX_NODES`` nodes, or is not a mapping.
    """
    p = Path(path)
    if not p.exists():
        raise ConfigFileError(f"{p}: no such file")
    if p.is_dir():
        raise ConfigFileError(f"{p}: is a directory, not a YAML file")
    if not p.is_file():
        raise ConfigFileError(f"{p}: not a regular file")
    size = p.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ConfigFileError(
            f"{p}: {size} bytes, too large for a configuration file (limit {MAX_FILE_BYTES})"
        )
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigFileError(f"{p}: cannot read ({exc.strerror})") from None
    try:
        if b"\x00" in raw:
            raise UnicodeDecodeError("utf-8", raw, 0, 1, "NUL byte")
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigFileError(f"{p}: a binary file, not YAML text (UTF-8)") from None
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        size = 0 if node is None else _expanded_size(node, {})
        data = None if node is None or size > MAX_NODES else loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigFileError(f"{p}: not valid YAML: {_yaml_problem(exc)}") from None
    except RecursionError:  # the parser recurses once per level of nesting
        raise ConfigFileError(f"{p}: nested more than {MAX_DEPTH} levels deep") from None
    finally:
        loader.dispose()
    if size > MAX_NODES:
        raise ConfigFileError(
            f"{p}: more than {MAX_NODES} YAML nodes once its aliases are expanded (an alias "
            "bomb?); write the settings out"
        )
    if data is None:
        raise ConfigFileError(f"{p}: the file is empty (no settings); write at least one field")
    if not isinstance(data, dict):
        raise ConfigFileError(
            f"{p}: expected a mapping (field: value) at the top level, got a "
            f"{type(data).__name__}"
        )
    return data
