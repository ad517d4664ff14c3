"""Parameter Data section: each entity's free-format parameters with typed, located access."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cadbridge.iges.directory import DirectoryEntry
from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import NOT_DELIMS, Record, RecordList, Token, TokenList, new_token, tokenize_lazy
from cadbridge.iges.values import MAX_TOKEN, parse_int_text, parse_real, parse_real_text

__all__ = ["Params", "read_params", "prepare_params", "FastTokens"]


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

    _f = None  # `_Fast` scan of the P section when the tokens are a `FastTokens` (else None)
    _t0 = 0  # index of this record's first token in the scan

    def __init__(self, entry: DirectoryEntry, tokens: list[Token] | TokenList, filename: str,
                 last_line: int) -> None:
        self.entry = entry
        self.tokens = tokens
        self._n = len(tokens)
        self._values: np.ndarray | bool | None = None  # all fields as floats, if they all are reals
        # token texts and string flags, read without building Token objects
        if isinstance(tokens, TokenList):
            self._texts_ = tokens.texts
            self._strings = None  # a TokenList holds no Hollerith strings
        else:
            self._texts_ = [t.text for t in tokens]
            self._strings = [t.is_string for t in tokens]
        self.filename = filename
        self.last_line = last_line  # line of the record delimiter's P line (for missing fields)

    @classmethod
    def _scanned(cls, entry: DirectoryEntry, tokens: "FastTokens", filename: str, last_line: int) -> "Params":
        """Params over a plain record of the compiled scan (texts made only when needed)."""
        self = cls.__new__(cls)
        self.entry = entry
        self.tokens = tokens
        self._n = tokens.n
        self._f = tokens.f
        self._t0 = tokens.t0
        self._rec_ok = tokens.rec_ok
        self._values = None
        self._texts_ = None
        self._strings = None
        self.filename = filename
        self.last_line = last_line
        return self

    @property
    def _texts(self) -> list[str]:
        t = self._texts_
        if t is None:
            t = self._texts_ = self.tokens.texts
        return t

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
        return 0 < k < self._n

    def require(self, last: int, what: str) -> None:
        """Raise unless fields 1..last exist (checked before any allocation)."""
        if last >= self._n:
            raise self.error(f"{what}: needs {last} parameters, the entity has {len(self.tokens) - 1}",
                             len(self.tokens), what)

    def int(self, k: int, name: str, default: int | None = None) -> int:
        if k >= self._n:
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        f = self._f
        if f is not None and k >= 0 and f.iex.item(self._t0 + k):  # a plain integer, converted by the scan
            return f.ival.item(self._t0 + k)
        try:
            return parse_int_text(self._texts[k], self._strings is not None and self._strings[k],
                                  0 if default is None else default)
        except ValueError as e:
            raise self.error(str(e), k, name) from None

    def real(self, k: int, name: str, default: float | None = None) -> float:
        if k >= self._n:
            if default is not None:
                return default
            raise self.error("missing parameter", k, name)
        f = self._f
        if f is not None and k >= 0 and f.nonempty_ok.item(self._t0 + k):  # a number, converted by the scan
            return f.fval.item(self._t0 + k)
        try:
            return parse_real_text(self._texts[k], self._strings is not None and self._strings[k],
                                   0.0 if default is None else default)
        except ValueError as e:
            raise self.error(str(e), k, name) from None

    def string(self, k: int, name: str, default: str | None = None) -> str:
        if k >= self._n:
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
        f = self._f
        if f is not None and start >= 0:
            i = self._t0 + start
            if self._rec_ok or f.ok[i : i + count].all():
                return f.values[i : i + count].copy()
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

    def check_values(self) -> None:
        """Raise IgesError at the first field (1-based) that is no IGES value: an integer, a
        real, a Hollerith string or empty (the default). Whether or not anything reads it."""
        f = self._f
        if f is not None and self._rec_ok:  # the scan converted every field
            return
        for k in range(1, self._n):
            if f is not None and f.ok.item(self._t0 + k):
                continue
            text = self._texts[k]
            if not text or (self._strings is not None and self._strings[k]):
                continue
            try:
                parse_real_text(text)
            except ValueError as e:
                why = str(e) if "overflows" in str(e) else (f"{text[:20]!r} is no IGES value (an integer, a real, "
                                                             "a Hollerith string or empty)")
                raise self.error(why, k, f"parameter {k}") from None

    def __repr__(self) -> str:
        return f"Params(DE {self.de}, type {self.etype}, {len(self)} fields)"


class _PSection:
    """Bulk view of a P section: columns 1-64 of all records joined (record i starts at
    64 * i) and each record's DE back pointer as an int (-1 when not plain digits).
    ``fast``: the compiled scan of the plain records (`_Fast`), or None."""

    __slots__ = ("n", "body", "back", "lines", "fast")

    def __init__(self, precs: list[Record], back: list[int] | None = None, body: str | None = None) -> None:
        self.n = len(precs)
        self.body = "".join([r.text[:64] for r in precs]) if body is None else body
        if back is None:
            self.back = [_back_int(r.text[65:72]) for r in precs]
        else:  # from the scan: -3 where it left the decision to `_back_int`
            for j in [j for j, v in enumerate(back) if v == -3]:
                back[j] = _back_int(precs[j].text[65:72])
            self.back = back
        n = self.n
        if n and precs[-1].line - precs[0].line == n - 1:  # increasing line numbers without gaps
            self.lines = list(range(precs[0].line, precs[0].line + n))
        else:
            self.lines = [r.line for r in precs]
        self.fast = None


class _Fast:
    """The compiled scan (`cadbridge.iges.pscan`) of one P section, as numpy arrays indexed by
    token: ``ival``/``iex`` integer value and whether it is exact (a plain integer field);
    ``fval``/``nonempty_ok`` real value and whether it is a number converted exactly (not
    empty); ``ok`` (numpy) the same but empty fields allowed (read as 0.0 by `Params.reals`);
    ``values`` (numpy) the reals; ``tstart``/``tend``/``trec`` field offsets in the body
    (stripped) and record index of the raw field's start. ``entity``: DE -> (first token,
    count, last record, whole record numeric), for the entry object scanned; ``delims`` the
    parameter and record delimiters of the scan."""

    __slots__ = ("body", "lines", "ival", "iex", "fval", "nonempty_ok", "ok", "values", "tstart", "tend", "trec",
                 "entity", "delims")


class FastTokens(Sequence):
    """The tokens of a plain record from the compiled scan, made on demand (like `TokenList`):
    a read-only list of `Token`s; ``texts`` and ``lines`` are built on first use."""

    __slots__ = ("f", "t0", "n", "rec_ok", "_texts", "_lines")

    def __init__(self, f: _Fast, t0: int, n: int, rec_ok: bool) -> None:
        self.f, self.t0, self.n, self.rec_ok = f, t0, n, rec_ok
        self._texts: list[str] | None = None
        self._lines: list[int] | None = None

    @property
    def texts(self) -> list[str]:
        if self._texts is None:
            f, a, b = self.f, self.t0, self.t0 + self.n
            body = f.body
            self._texts = [body[s:e] for s, e in zip(f.tstart[a:b].tolist(), f.tend[a:b].tolist())]
        return self._texts

    @property
    def lines(self) -> list[int]:
        if self._lines is None:
            ln = self.f.lines
            self._lines = [ln[r] for r in self.f.trec[self.t0 : self.t0 + self.n].tolist()]
        return self._lines

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(self.n))]
        return new_token(Token, (self.texts[k], self.lines[k], False))

    def __iter__(self):
        for text, line in zip(self.texts, self.lines):
            yield new_token(Token, (text, line, False))

    def __eq__(self, other) -> bool:
        return list(self) == list(other) if isinstance(other, (list, TokenList, FastTokens)) else NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"FastTokens({list(self)!r})"


SCAN_MIN_RECORDS = 0  # P sections shorter than this are read by the Python path alone


def prepare_params(entries: dict[int, DirectoryEntry], precs: list[Record], pdelim: str, rdelim: str) -> None:
    """Scan the whole P section once (compiled kernel) for `read_params`'s fast path. Does
    nothing (the Python path then reads every record) for a short section, records not of
    72 columns, delimiters the kernel cannot take, or when numba is unavailable."""
    if not isinstance(precs, RecordList) or len(precs) < SCAN_MIN_RECORDS or not precs:
        return
    if isinstance(precs.derived, _PSection) and precs.derived.n == len(precs) and precs.derived.fast is not None:
        return
    if (len(pdelim) != 1 or len(rdelim) != 1 or pdelim in NOT_DELIMS or rdelim in NOT_DELIMS
            or not (32 < ord(pdelim) < 127 and 32 < ord(rdelim) < 127) or pdelim == rdelim):
        return
    raw = "".join([r.text for r in precs])
    if len(raw) != 72 * len(precs):
        return
    try:
        from cadbridge.iges.pscan import scan_parameters
    except ImportError:  # pragma: no cover - numba missing: the Python path alone
        return
    ents = list(entries.values())
    raw_b = raw.encode("latin-1")
    (back, status, t_first, t_count, last_rec, all_ok, tstart, tend, trec, kind, exact, ival,
     fval) = scan_parameters(raw_b, len(precs), [e.param_pointer - 1 for e in ents],
                             [e.param_count for e in ents], [e.de for e in ents], [e.entity_type for e in ents],
                             pdelim, rdelim, MAX_TOKEN)
    # columns 1-64 joined, from the bytes the scan read (latin-1: one character per byte)
    body = np.frombuffer(raw_b, dtype=np.uint8).reshape(len(precs), 72)[:, :64].tobytes().decode("latin-1")
    bulk = _PSection(precs, back.tolist(), body)
    f = _Fast()
    f.body = bulk.body
    f.lines = bulk.lines
    fexact = (exact & 1).astype(bool)
    # valid numbers the kernel could not convert exactly: Python's float, in one batch
    redo = np.flatnonzero((kind != 3) & ~fexact)
    if redo.size:
        body = bulk.body
        texts = [body[s:e] for s, e in zip(tstart[redo].tolist(), tend[redo].tolist())]
        try:  # plain E (or no) exponents: C-level conversion of the whole batch
            vals = np.array(list(map(float, texts)))
        except ValueError:  # a Fortran D exponent somewhere
            vals = np.array([float(t.replace("D", "E").replace("d", "e")) for t in texts])
        fval[redo] = vals
        fexact[redo] = np.isfinite(vals)  # an overflow is reported by the Python path
    ok = fexact & (kind != 3)
    f.ok = ok
    f.values = fval
    # numpy arrays read one item at a time (`.item`: Python scalars); lists of every token's
    # value would cost more to build and free than the few fields the builder reads one by one
    f.fval = fval
    f.nonempty_ok = ok & (kind != 0)
    f.iex = (exact & 2) != 0
    f.ival = ival
    f.tstart, f.tend, f.trec = tstart, tend, trec  # numpy: sliced per record when texts are needed
    sel = np.flatnonzero(status)
    if redo.size and sel.size:  # the batch may have turned a record non-numeric (overflow)
        all_ok[sel] = np.logical_and.reduceat(ok, t_first[sel])
    f.delims = (pdelim, rdelim)
    des = [ents[k] for k in sel.tolist()]
    f.entity = dict(zip([e.de for e in des], zip(des, t_first[sel].tolist(), t_count[sel].tolist(),
                                                  last_rec[sel].tolist(), all_ok[sel].astype(bool).tolist())))
    bulk.fast = f
    precs.derived = bulk


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
    f = bulk.fast
    if f is not None:
        hit = f.entity.get(entry.de)
        if hit is not None and hit[0] is entry and f.delims == (pdelim, rdelim):
            _, a, c, r, rec_ok = hit
            return Params._scanned(entry, FastTokens(f, a, c, rec_ok), filename, bulk.lines[r])
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
    if pdelim in NOT_DELIMS or rdelim in NOT_DELIMS:
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
