"""Reading YAML documents that a user (or an attacker) wrote: strict and bounded.

:func:`load_yaml_file` parses with PyYAML's safe loader plus four guards,
each giving one :class:`~rigslim.errors.PipelineError` line with the line
number:

- a mapping that repeats a key is refused (PyYAML silently keeps the last
  one, so a second ``steps:`` would replace the first);
- aliases may not expand to more than :data:`MAX_NODES` values in all (a
  "billion laughs" document is a few lines that expand to gigabytes once
  anything walks it);
- nesting deeper than :data:`MAX_DEPTH` is refused (no pipeline needs it,
  and recursive walkers would overflow the stack);
- the file must be UTF-8 text no larger than :data:`MAX_BYTES`.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from rigslim.errors import PipelineError, brief

#: Most values (scalars, lists, mappings) a document may hold once aliases are expanded.
MAX_NODES = 200_000
#: Deepest nesting of lists and mappings.
MAX_DEPTH = 64
#: Largest YAML file read (bytes).
MAX_BYTES = 16 << 20


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key, mark, first):
        self.key, self.mark, self.first = key, mark, first


class StrictLoader(yaml.SafeLoader):
    """Safe loader that refuses repeated keys in a mapping."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    hash(key)
                except TypeError:
                    continue  # SafeConstructor reports unhashable keys itself
                if key in seen:
                    raise _DuplicateKey(key, key_node.start_mark, seen[key])
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _measure(root) -> tuple[int, int]:
    """(expanded value count, depth) of a composed node graph, aliases counted at every use.

    Memoised on node identity, so it costs one visit per distinct node even
    for a document that expands exponentially; stops counting at MAX_NODES + 1.
    """
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    stack = [(root, False)]
    on_path: set[int] = set()
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if not done:
            if key in size:
                continue
            if key in on_path:  # a recursive alias (&a [*a]): infinite once expanded
                size[key], depth[key] = MAX_NODES + 1, MAX_DEPTH + 1
                continue
            on_path.add(key)
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in size)
            continue
        on_path.discard(key)
        total = 1 + sum(size.get(id(c), MAX_NODES + 1) for c in children)
        size[key] = min(total, MAX_NODES + 1)
        depth[key] = 1 + max((depth.get(id(c), MAX_DEPTH + 1) for c in children), default=0)
    return size[id(root)], depth[id(root)]


def _problem(e: yaml.YAMLError) -> tuple[str, str]:
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "YAML"
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    return where, problem


def load_yaml_text(text: str, source) -> object:
    """Parse one YAML document with the guards of the module docstring."""
    try:
        loader = StrictLoader(text)  # the reader refuses control characters here already
    except yaml.YAMLError as e:
        where, problem = _problem(e)
        raise PipelineError(f"malformed YAML ({problem})", source=source, field=where,
                            fix="remove control characters; give a YAML text file") from None
    try:
        try:
            node = loader.get_single_node()
        except RecursionError:
            raise PipelineError(f"the document is nested more than {MAX_DEPTH} levels deep", source=source,
                                field="YAML", fix="flatten the document") from None
        if node is None:
            return None
        count, depth = _measure(node)
        if depth > MAX_DEPTH:
            raise PipelineError(f"the document is nested more than {MAX_DEPTH} levels deep", source=source,
                                field=f"line {node.start_mark.line + 1}", fix="flatten the document")
        if count > MAX_NODES:
            raise PipelineError(f"aliases expand the document to more than {MAX_NODES} values", source=source,
                                field="YAML anchors/aliases", fix="write the values out instead of nesting aliases")
        try:
            return loader.construct_document(node)
        except _DuplicateKey as e:
            raise PipelineError(f"key {brief(e.key)} is given twice (first on line {e.first.line + 1})",
                                source=source, field=f"line {e.mark.line + 1}",
                                fix="remove or rename one of them (the second would silently replace the first)"
                                ) from None
    except yaml.YAMLError as e:
        where, problem = _problem(e)
        raise PipelineError(f"malformed YAML ({problem})", source=source, field=where,
                            fix="fix the YAML syntax (indentation, colons, quotes)") from None
    finally:
        loader.dispose()


def load_yaml_file(path) -> object:
    """Read and parse a YAML file (UTF-8 text, at most MAX_BYTES) with the module's guards."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise PipelineError(f"cannot read pipeline ({e.strerror})", source=path, field="path",
                            fix="check the path") from None
    if len(data) > MAX_BYTES:
        raise PipelineError(f"the file is larger than {MAX_BYTES >> 20} MiB", source=path, field="path",
                            fix="give a YAML pipeline file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise PipelineError(f"not UTF-8 text (byte {data[e.start]:#04x} at offset {e.start})", source=path,
                            field="path", fix="give a YAML pipeline file") from None
    if "\x00" in text:
        raise PipelineError("not a text file (it holds NUL bytes)", source=path, field="path",
                            fix="give a YAML pipeline file")
    return load_yaml_text(text, path)
