"""YAML read strictly: ``yaml.safe_load`` that refuses a mapping key written twice.

PyYAML keeps the last of two equal keys without a word (YAML 1.2 says keys must be unique), so a
settings file with two ``prognosis:`` blocks silently dropped the first. Every parameters and
settings file of the package is read with :func:`safe_load` here; the refusal is a
``yaml.YAMLError`` (a ``ConstructorError`` whose first line names the key and both lines), so each
reader's existing "not valid YAML" message carries it.
"""
from __future__ import annotations

from typing import Any

import yaml

_MERGE = "tag:yaml.org,2002:merge"


class SafeUniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` refusing a key written twice in one mapping. Keys brought in by a merge
    (``<<: *anchor``) may be overridden, as YAML's merge key allows."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE:
                    continue
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    first = seen.get(key)
                except TypeError:          # an unhashable key: SafeLoader's own error follows
                    continue
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} written twice (lines {first} and {line}): "
                        "which one is meant is not clear", key_node.start_mark)
                seen[key] = line
        return super().construct_mapping(node, deep=deep)


def safe_load(text: str) -> Any:
    """``yaml.safe_load(text)`` that refuses a mapping key written twice (:class:`SafeUniqueKeyLoader`)."""
    return yaml.load(text, Loader=SafeUniqueKeyLoader)   # a SafeLoader subclass (tests/test_untrusted.py reads the name)
