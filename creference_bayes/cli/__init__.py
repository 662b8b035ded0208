"""The ``creference`` command line, one module per command group (:mod:`.main` holds the parser)."""

from .estimate import format_tables
from .main import EXIT_INVALID, UsageError, build_parser, example_scene_path, main

__all__ = ["main", "build_parser", "example_scene_path", "format_tables", "UsageError", "EXIT_INVALID"]
