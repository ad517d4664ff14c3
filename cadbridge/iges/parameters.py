"""Parameter Data section: each entity's free-format parameters with typed, located access."""

from __future__ import annotations

import numpy as np

from cadbridge.iges.directory import DirectoryEntry
from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import _NOT_DELIMS, Record, RecordList, Token, TokenList, tokenize_lazy
from cadbridge.iges.values import MAX_TOKEN, parse_int_text, parse_real, parse_real_text

__all__ = ["Params", "read_params"]


_DROP_REAL_CHARS = str.maketrans("", "", "0123456789.+-EeDd\n")  # deletes the real alphabet
_INF = float("inf")
_D_TO_E = str.maketrans("Dd", "Ee")


def _reals_plain(texts: list[str]) -> np.ndarray | None:
    """Bulk conversion for `Params.reals` when every token is a plain, non-empty number of
    at most MAX_TOKEN characters drawn from digits, ``.+-`` and ``EeDd``: over that alphabet
    Python's ``float`` accepts exactly the IGES real syntax of `parse_real` (once ``D`` is
    read as ``E``). None when the fast path does not apply or a value is rejected or
    overflows; the caller then converts token by token and reports the exact field."""
    if not texts:
        return np.empty(0)
    joined = "\n".join(texts)
    if len(joined) > MAX_TOKEN and max(map(len, texts)) > MAX_TOKEN:
        return None
    if joined.translate(_DROP_REAL_CHARS):  # a character outside the alphabet
        return None
    if "D" in joined or "d" in joined:  # Fortran exponent letter
        texts = joined.translate(_D_TO_E).split("\n")
    try:  # float("") raises too: empty fields take the token-by-token path (default value)
        vals = list(map(float, texts))
    except ValueError:
        return None
    if _INF in vals or -_INF in vals:  # overflow: reported by the token-by-token path
        return None
    return np.array(vals)


class Params:
    """The parameter list of one entity. Field ``k`` (1-based, as numbered in the IGES
    specification) is ``tokens[k]``; ``tokens[0]`` is the entity type.

    Every accessor raises `IgesError` naming the file line, DE, entity type and field.
    """

    def __init__(self, entry: DirectoryEntry, tokens: list[Token] | TokenList, filename: str,
                 last_line: int) -> None:
        self.entry = entry
        self.tokens = tokens
        self._values: np.ndarray | bool | None = None  # all fields as floats, if they all are reals
        # token texts and string flags, read without building Token objects
        if isinstance(tokens, TokenList):
            self._texts = tokens.texts
            self._strings = None  # a TokenList holds no Hollerith strings
        else:
            self._texts = [t.text for t in tokens]
            self._strings = [t.is_string for t in tokens]
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
            return parse_int_text(self._texts[k], self._strings is not None and self._strings[k],
                                  0 if default is None else default)
        except ValueError as e:
            raise self.error(str(e), k, name) from None

    def real(self, k: int, name: str, default: float | None = None) -> float:
        if k >= len(self.tokens):
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        try:
            return parse_real_text(self._texts[k], self._strings is not None and self._strings[k],
                                   0.0 if default is None else default)
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
        toks = self.tokens
        if self._values is None and self._strings is None:
            # first call: convert the whole record at once (fails on empty fields etc.)
            self._values = _reals_plain(self._texts)
            if self._values is None:
                self._values = False
        if self._values is not False and self._values is not None:
            return self._values[start : start + count].copy()
        if self._strings is None or not any(self._strings[start : start + count]):
            fast = _reals_plain(self._texts[start : start + count])
            if fast is not None:
                return fast
        out = np.empty(count)
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


class _PSection:
    """Bulk view of a P section: columns 1-64 of all records joined (record i starts at
    64 * i) and each record's DE back pointer as an int (-1 when not plain digits)."""

    __slots__ = ("n", "body", "back", "lines")

    def __init__(self, precs: list[Record]) -> None:
        self.n = len(precs)
        self.body = "".join([r.text[:64] for r in precs])
        self.back = [_back_int(r.text[65:72]) for r in precs]
        self.lines = [r.line for r in precs]


def _back_int(field: str) -> int:
    """DE back pointer as an int; -1 when not digits, -2 for non-ASCII digits (which the
    general path treats its own way)."""
    s = field.strip()
    if not s.isdigit():
        return -1
    return int(s) if s.isascii() else -2


def _read_params_bulk(entry: DirectoryEntry, precs: RecordList, pdelim: str, rdelim: str,
                      filename: str) -> Params | None:
    """`read_params` for the regular case, on the P section's bulk view (no per-line chunk
    list, no join): all of the entry's lines carry its DE, the record has no Hollerith
    string and ends with the record delimiter within those lines, the first field is the
    entity type. None otherwise (the general path then produces the exact error)."""
    bulk = precs.derived
    if not isinstance(bulk, _PSection) or bulk.n != len(precs):
        bulk = precs.derived = _PSection(precs)
    if len(bulk.body) != 64 * bulk.n:  # records not padded to 72 columns: general path
        return None
    de = entry.de
    a = entry.param_pointer - 1
    if a < 0 or a >= bulk.n:
        return None
    b = min(a + max(entry.param_count, 1), bulk.n)
    back = bulk.back
    if back[a:b].count(de) != b - a:
        return None
    while b < bulk.n and back[b] == de:  # sloppy files: the record continues past the line count
        b += 1
    if b < bulk.n and back[b] == -2:
        return None
    if pdelim in _NOT_DELIMS or rdelim in _NOT_DELIMS:
        return None
    j_r = bulk.body.find(rdelim, 64 * a, 64 * b)
    if j_r < 0:
        return None
    seg = bulk.body[64 * a : j_r]
    if "H" in seg or "h" in seg:
        return None
    parts = seg.split(pdelim)
    try:
        if parse_int_text(parts[0].strip()) != entry.entity_type:
            return None
    except ValueError:
        return None
    toks = TokenList(list(map(str.strip, parts)), parts, bulk.lines[a:b], 64)
    return Params(entry, toks, filename, bulk.lines[b - 1])


def read_params(entry: DirectoryEntry, precs: list[Record], pdelim: str, rdelim: str, filename: str) -> Params:
    """Tokenise the P lines of ``entry`` (columns 1-64), checking the DE back pointers
    (columns 66-72) and that the first parameter is the entity type."""
    if isinstance(precs, RecordList):
        p = _read_params_bulk(entry, precs, pdelim, rdelim, filename)
        if p is not None:
            return p
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
    toks = tokenize_lazy(chunks, pdelim, rdelim, filename, de=entry.de, entity_type=entry.entity_type)
    p = Params(entry, toks, filename, chunks[-1][1])
    try:
        v = parse_int_text(p._texts[0], p._strings is not None and p._strings[0]) if p._texts else None
    except ValueError:
        v = None
    if v != entry.entity_type:
        t0 = toks[0] if toks else None
        raise IgesError(f"first parameter {t0.text if t0 else ''!r} is not the entity type {entry.entity_type}",
                        filename=filename, line=chunks[0][1], de=entry.de, entity_type=entry.entity_type,
                        field="entity type")
    return p
