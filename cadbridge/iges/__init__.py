"""IGES 5.3 reading and writing.

Modules: ``lexer`` (sections, free-format tokens), ``globals`` (Global section, units),
``directory`` (directory entries), ``parameters`` (typed, located parameter access),
``entities`` (geometry construction), ``reader`` (`read_iges`), ``writer`` (`write_iges`).
"""

from cadbridge.iges.errors import IgesError
from cadbridge.iges.reader import read_iges, read_iges_string
from cadbridge.iges.writer import write_iges

__all__ = ["IgesError", "read_iges", "read_iges_string", "write_iges"]
