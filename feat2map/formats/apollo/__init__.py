"""Apollo HD maps (protobuf `apollo.hdmap.Map`, Apollo 5-9): read (`reader`), write base_map,
sim_map and routing_map (`writer`, `sim_map`, `routing`), check what Apollo needs (`validate`,
`picture`). `schema` builds Apollo's message classes in Python from a table of its public field
names and numbers; `geometry` holds the lane geometry Apollo's files record."""
from __future__ import annotations

from .picture import render_apollo, render_problems
from .reader import base_map_file, read_apollo, read_apollo_bytes
from .validate import load_base_map, validate_apollo
from .writer import FILES, to_apollo, write_apollo

__all__ = ["FILES", "base_map_file", "load_base_map", "read_apollo", "read_apollo_bytes", "render_apollo",
           "render_problems", "to_apollo", "validate_apollo", "write_apollo"]
