"""The exceptions splat4d raises: one class per kind of library error.

Each carries the library's message (the command line's, naming the file, the item and
the field) and, as attributes, the names it blames: ``origin`` (a file, or ``<scene>`` for
arrays), ``item`` (``kernel 3``, a frame), ``field`` (``scale``), and ``settings`` (the
options a setting error blames, named like ``fit``'s keyword options).
"""

from typing import List, Optional


class Splat4dError(Exception):
    """Any error of the splat4d library."""

    origin: Optional[str] = None
    item: Optional[str] = None
    field: Optional[str] = None
    settings: List[str] = []


class InputError(Splat4dError, ValueError):
    """An input could not be read, is not well-formed, or holds an invalid value."""


class UsageError(Splat4dError, ValueError):
    """A request that cannot be carried out as asked (contradicting options, wrong shapes)."""


class OutputError(Splat4dError, OSError):
    """An output could not be written."""


class NumericError(Splat4dError, ArithmeticError):
    """A computation left the finite numbers (a fit diverged, a result is not finite)."""
