"""Parameter Data section: each entity's free-format parameters with typed, located access."""

from __future__ import annotations

import numpy as np

from cadbridge.iges.directory import DirectoryEntry
from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record, Token, tokenize
from cadbridge.iges.values import parse_int, parse_real

__all__ = ["Params", "read_params"]


class Params:
    """The parameter list of one entity. Field ``k`` (1-based, as numbered in the IGES
    specification) is ``tokens[k]``; ``tokens[0]`` is the entity type.

    Every accessor raises `IgesError` naming the file line, DE, entity type and field.
    """

    def __init__(self, entry: DirectoryEntry, tokens: list[Token], filename: str, last_line: int) -> None:
        self.entry = entry
        self.tokens = tokens
        self.filename = filename
        self.last_line = last_line  # line of the record delimiter's P line (for missing fields)

    @property
    def de(self) -> int:
        return self.entry.de

    @property
    def etype(self) -> int:
        return self.entry.entity_type

    def __len__(self) -> int:
        """Number of fields after the entity type."""
        return len(self.tokens) - 1

    def error(self, message: str, k: int | None = None, name: str | None = None) -> IgesError:
        """An IgesError located at field k (or the entity's first P line)."""
        if k is not None and 0 <= k < len(self.tokens):
            line = self.tokens[k].line
        elif k is not None:
            line = self.last_line
        else:
            line = self.tokens[0].line if self.tokens else self.entry.line
        return IgesError(message, filename=self.filename, line=line, de=self.de, entity_type=self.etype,
                         field=name if name is not None else (f"#{k}" if k is not None else None))

    def line(self, k: int) -> int:
        return self.tokens[k].line if 0 <= k < len(self.tokens) else self.last_line

    def has(self, k: int) -> bool:
        return 0 < k < len(self.tokens)

    def require(self, last: int, what: str) -> None:
        """Raise unless fields 1..last exist (checked before any allocation)."""
        if last >= len(self.tokens):
            raise self.error(f"{what}: needs {last} parameters, the entity has {len(self.tokens) - 1}",
                             len(self.tokens), what)

    def int(self, k: int, name: str, default: int | None = None) -> int:
        if k >= len(self.tokens):
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        try:
            return parse_int(self.tokens[k], 0 if default is None else default)
        except ValueError as e:
            raise self.error(str(e), k, name) from None

    def real(self, k: int, name: str, default: float | None = None) -> float:
        if k >= len(self.tokens):
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        try:
            return parse_real(self.tokens[k], 0.0 if default is None else default)
        except ValueError as e:
            raise self.error(str(e), k, name) from None

    def string(self, k: int, name: str, default: str | None = None) -> str:
        if k >= len(self.tokens):
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        t = self.tokens[k]
        if t.is_string:
            return t.text
        if t.text == "":
            return "" if default is None else default
        raise self.error(f"expected a Hollerith string, got {t.text[:20]!r}", k, name)

    def reals(self, start: int, count: int, name: str) -> np.ndarray:
        """Fields start..start+count-1 as a float array (count already validated)."""
        self.require(start + count - 1, name)
        out = np.empty(count)
        toks = self.tokens
        for j in range(count):
            tok = toks[start + j]
            try:
                out[j] = parse_real(tok)
            except ValueError as e:
                raise self.error(str(e), start + j, f"{name}[{j}]") from None
        return out

    def pointer(self, k: int, name: str, allow_zero: bool = True, default: int | None = None) -> int:
        """A DE pointer field (absolute value taken for negated pointers). Existence is
        checked by the entity builder, which knows the directory."""
        p = self.int(k, name, default)
        if p == 0 and not allow_zero:
            raise self.error("null pointer where an entity is required", k, name)
        return abs(p)

    def __repr__(self) -> str:
        return f"Params(DE {self.de}, type {self.etype}, {len(self)} fields)"


def read_params(entry: DirectoryEntry, precs: list[Record], pdelim: str, rdelim: str, filename: str) -> Params:
    """Tokenise the P lines of ``entry`` (columns 1-64), checking the DE back pointers
    (columns 66-72) and that the first parameter is the entity type."""
    start = entry.param_pointer
    count = max(entry.param_count, 1)
    if start < 1 or start > len(precs):
        raise IgesError(f"parameter data pointer {start} outside the P section (1..{len(precs)})",
                        filename=filename, line=entry.line, de=entry.de, entity_type=entry.entity_type,
                        field="parameter data")
    end = min(start - 1 + count, len(precs))
    chunks = []
    for rec in precs[start - 1 : end]:
        back = rec.text[65:72].strip()
        if back != str(entry.de):
            # some writers pad with zeros or leave room differently: compare numerically
            if not (back.isdigit() and int(back) == entry.de):
                raise IgesError(f"P line belongs to DE {back or '(blank)'}, expected {entry.de}",
                                filename=filename, line=rec.line, de=entry.de, entity_type=entry.entity_type,
                                field="DE back pointer")
        chunks.append((rec.text[:64], rec.line))
    # a record may continue past the stated line count in sloppy files: extend while back pointer agrees
    k = end
    while k < len(precs) and precs[k].text[65:72].strip().isdigit() and int(precs[k].text[65:72]) == entry.de:
        chunks.append((precs[k].text[:64], precs[k].line))
        k += 1
    toks = tokenize(chunks, pdelim, rdelim, filename, de=entry.de, entity_type=entry.entity_type)
    p = Params(entry, toks, filename, chunks[-1][1])
    t0 = toks[0] if toks else None
    try:
        v = parse_int(t0) if t0 is not None else None
    except ValueError:
        v = None
    if v != entry.entity_type:
        raise IgesError(f"first parameter {t0.text if t0 else ''!r} is not the entity type {entry.entity_type}",
                        filename=filename, line=chunks[0][1], de=entry.de, entity_type=entry.entity_type,
                        field="entity type")
    return p
