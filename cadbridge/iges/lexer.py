"""Fixed-format IGES records: split a file into its S, G, D, P, T sections, and tokenise
free-format parameter text (Global and Parameter Data sections).

A *record* is one 80-column line: columns 1-72 data, column 73 the section letter,
columns 74-80 the sequence number. Every token keeps the file line number it starts on,
so any later error can point at the line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from itertools import accumulate, repeat
from operator import itemgetter
from collections.abc import Sequence
from typing import NamedTuple

from cadbridge.iges.errors import IgesError

__all__ = ["NOT_DELIMS", "Record", "RecordList", "Sections", "Token", "TokenList", "new_token", "split_sections", "tokenize",
           "tokenize_lazy"]

SECTION_ORDER = "SGDPT"


class Record(NamedTuple):
    """One line of a section: ``text`` is columns 1-72 (padded to 72), ``line`` the 1-based
    line number in the file, ``seq`` the sequence number from columns 74-80. (An immutable
    named tuple rather than a frozen dataclass: a file has one per line, and tuples are
    several times cheaper to create.)"""

    text: str
    line: int
    seq: int


class RecordList(list):
    """A plain list of `Record`s that can also carry data derived from it (``derived``,
    e.g. the parameter reader's bulk view of the P section), living as long as the list."""

    derived: object = None


@dataclass
class Sections:
    """The records of each section, in file order, plus reader notes (line, message)."""

    start: list[Record] = field(default_factory=list)
    global_: list[Record] = field(default_factory=list)
    directory: list[Record] = field(default_factory=list)
    parameter: list[Record] = field(default_factory=RecordList)
    terminate: list[Record] = field(default_factory=list)
    notes: list[tuple[int, str]] = field(default_factory=list)


def _lines(text: str) -> list[str]:
    lines = text.splitlines()
    # files written as one long string of 80-column records (no line breaks)
    if len(lines) == 1 and len(lines[0]) > 80 and len(lines[0]) % 80 == 0:
        s = lines[0]
        lines = [s[i : i + 80] for i in range(0, len(s), 80)]
    return lines


_LETTER = itemgetter(72)
_DATA = itemgetter(slice(0, 72))
_SEQ_FIELD = itemgetter(slice(73, 80))
_DROP_DIGITS_BLANKS = str.maketrans("", "", "0123456789 ")
_SECTION_RUNS = re.compile(r"(S*)(G+)(D*)(P*)(T?)")


def _split_regular(lines: list[str], filename: str) -> Sections | None:
    """`split_sections` for the regular file, checked in bulk: every line exactly 80
    columns, sections S G D P T in order (G present, at most one T line, even D count),
    sequence numbers 1, 2, ... in each. None otherwise: the line-by-line scanner then
    reads the file and reports the first problem with its line number."""
    if not lines or set(map(len, lines)) != {80}:
        return None
    runs = _SECTION_RUNS.fullmatch("".join(map(_LETTER, lines)))
    if runs is None or len(runs.group(3)) % 2:
        return None
    fields = list(map(_SEQ_FIELD, lines))
    if "".join(fields).translate(_DROP_DIGITS_BLANKS):
        return None
    try:  # digits and blanks only: int() fails on an all-blank field or inner blanks
        seqs = list(map(int, fields))
    except ValueError:
        return None
    secs = Sections()
    pos = 0
    for recs, run in zip((secs.start, secs.global_, secs.directory, secs.parameter, secs.terminate),
                         runs.groups()):
        m = len(run)
        if seqs[pos : pos + m] != list(range(1, m + 1)):
            return None
        # Record(line[:72], file line, seq) for each line of the run, built in C (map/zip)
        recs.extend(map(_new_record, repeat(Record), zip(map(_DATA, lines[pos : pos + m]),
                                                         range(pos + 1, pos + m + 1), range(1, m + 1))))
        pos += m
    if not secs.terminate:
        secs.notes.append((len(lines), "no Terminate (T) section: file may be truncated"))
    else:
        _check_terminate(secs, filename)
    return secs


_new_record = tuple.__new__


def split_sections(text: str, filename: str) -> Sections:
    """Split file text into sections, checking section letters, order and sequence numbers.

    Raises IgesError for compressed/binary files, unknown section letters, sections out of
    order, broken sequence numbers, or an empty file. A missing T section is only noted.
    """
    if "\x00" in text[:4096]:
        raise IgesError("binary IGES is not supported (NUL bytes found)", filename=filename, line=1)
    lines = _lines(text)
    fast = _split_regular(lines, filename)
    if fast is not None:
        return fast
    secs = Sections()
    by_letter = {"S": secs.start, "G": secs.global_, "D": secs.directory, "P": secs.parameter, "T": secs.terminate}
    current = -1
    # 1-based number of the last line with content (blank lines before it get a note)
    last_content = len(lines)
    while last_content > 0 and not lines[last_content - 1].strip():
        last_content -= 1
    recs: list[Record] = []
    letter_now = ""
    new_record = tuple.__new__
    for i, raw in enumerate(lines, start=1):
        # fast path: a full 80-column record continuing the current section in sequence
        if len(raw) == 80 and raw[72] == letter_now:
            seq_text = raw[73:80].strip()
            if seq_text.isdigit():
                seq = int(seq_text)
                if seq == len(recs) + 1:
                    recs.append(new_record(Record, (raw[:72], i, seq)))
                    continue
        s = raw.rstrip("\r\n\x1a")
        if not s.strip():
            if i < last_content:
                secs.notes.append((i, "blank line skipped"))
            continue
        if len(s) > 80:
            if s[80:].strip():
                raise IgesError(f"line is {len(s)} characters long; fixed-format records have 80",
                                filename=filename, line=i)
            s = s[:80]
        s = s.ljust(80)
        letter = s[72]
        if letter == "C" and current < 0:
            raise IgesError("compressed ASCII IGES (C in column 73) is not supported", filename=filename, line=i)
        if letter == "B" and current < 0:
            raise IgesError("binary IGES (B in column 73) is not supported", filename=filename, line=i)
        if letter not in SECTION_ORDER:
            raise IgesError(f"column 73 holds {letter!r}, not a section letter (S, G, D, P or T)",
                            filename=filename, line=i)
        k = SECTION_ORDER.index(letter)
        if k < current:
            raise IgesError(f"section {letter} after section {SECTION_ORDER[current]}: sections out of order",
                            filename=filename, line=i)
        if current == 4:
            raise IgesError("data after the Terminate section", filename=filename, line=i)
        current = k
        seq_text = s[73:80].strip()
        if not seq_text.isdigit():
            raise IgesError(f"sequence number {s[73:80]!r} in columns 74-80 is not a number",
                            filename=filename, line=i)
        seq = int(seq_text)
        recs = by_letter[letter]
        if seq != len(recs) + 1:
            raise IgesError(f"section {letter}: sequence number {seq}, expected {len(recs) + 1}",
                            filename=filename, line=i)
        recs.append(Record(s[:72], i, seq))
        letter_now = letter if letter != "T" else ""  # nothing may follow T: general path
    if not (secs.start or secs.global_ or secs.directory):
        raise IgesError("empty file or no IGES sections found", filename=filename, line=1)
    if not secs.global_:
        raise IgesError("no Global (G) section", filename=filename, line=len(lines) or 1)
    if len(secs.directory) % 2:
        rec = secs.directory[-1]
        raise IgesError("Directory section has an odd number of lines (truncated entry)",
                        filename=filename, line=rec.line)
    if not secs.terminate:
        secs.notes.append((len(lines), "no Terminate (T) section: file may be truncated"))
    else:
        _check_terminate(secs, filename)
    return secs


def _check_terminate(secs: Sections, filename: str) -> None:
    t = secs.terminate[0].text
    want = {"S": len(secs.start), "G": len(secs.global_), "D": len(secs.directory), "P": len(secs.parameter)}
    for j, letter in enumerate("SGDP"):
        chunk = t[8 * j : 8 * j + 8]
        if chunk[:1] != letter or not chunk[1:].strip().isdigit():
            secs.notes.append((secs.terminate[0].line, f"Terminate section: field {letter} unreadable ({chunk!r})"))
            continue
        if int(chunk[1:]) != want[letter]:
            secs.notes.append((secs.terminate[0].line,
                               f"Terminate section says {int(chunk[1:])} {letter} lines, file has {want[letter]}"))


class Token(NamedTuple):
    """One free-format parameter: ``text`` stripped of blanks (the characters of a Hollerith
    string, without ``nH``, when ``is_string``), ``line`` the file line it starts on.
    (An immutable named tuple, like `Record`, for speed.)"""

    text: str
    line: int
    is_string: bool = False


_HOLLERITH = re.compile(r"\s*(\d+)[Hh]")


new_token = tuple.__new__  # Token(text, line, is_string) without the keyword-argument wrapper
NOT_DELIMS = frozenset("Hh0123456789 ")  # delimiters the fast path cannot take (Hollerith syntax)


class TokenList(Sequence):
    """The tokens of a record without Hollerith strings, made on demand: ``texts`` holds the
    stripped token texts; the file line of each token is computed (from the token offsets
    and the fixed chunk width) only when asked for. Behaves as a read-only list of `Token`s
    (indexing, slicing, iteration, len); slices are plain lists."""

    __slots__ = ("texts", "_parts", "_chunk_lines", "_size", "_lines")

    def __init__(self, texts: list[str], parts: list[str], chunk_lines: list[int], size: int) -> None:
        self.texts = texts
        self._parts = parts
        self._chunk_lines = chunk_lines
        self._size = size
        self._lines: list[int] | None = None

    @property
    def lines(self) -> list[int]:
        """File line of each token (the line its first character is on)."""
        if self._lines is None:
            cl, size = self._chunk_lines, self._size
            if len(cl) == 1:
                self._lines = [cl[0]] * len(self.texts)
            else:  # token k starts at sum(len(part) + 1 for the parts before it)
                starts = accumulate((len(part) + 1 for part in self._parts[:-1]), initial=0)
                self._lines = [cl[pos // size] for pos in starts]
        return self._lines

    def __len__(self) -> int:
        return len(self.texts)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self.texts)))]
        return new_token(Token, (self.texts[k], self.lines[k], False))

    def __iter__(self):
        for text, line in zip(self.texts, self.lines):
            yield new_token(Token, (text, line, False))

    def __eq__(self, other) -> bool:
        return list(self) == list(other) if isinstance(other, (list, TokenList)) else NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"TokenList({list(self)!r})"


def _tokenize_plain(text: str, chunks: list[tuple[str, int]], pdelim: str, rdelim: str,
                    max_tokens: int | None) -> TokenList | None:
    """Fast path of `tokenize` for the common record without Hollerith strings: one
    ``str.split`` up to the first record delimiter, lines from token offsets (on demand).
    Returns None (the caller then runs the general scanner, which also produces every
    error) when there is no record delimiter, an ``H`` before it (a possible string), too
    many tokens or chunks of unequal width."""
    if pdelim in NOT_DELIMS or rdelim in NOT_DELIMS:
        return None
    j_r = text.find(rdelim)
    if j_r < 0:
        return None
    body = text[:j_r]
    if "H" in body or "h" in body:
        return None
    parts = body.split(pdelim)
    if max_tokens is not None and len(parts) - 1 > max_tokens:
        return None
    size = len(chunks[0][0])
    if size == 0 or any(len(c) != size for c, _ in chunks):  # unequal chunks: general path
        return None
    return TokenList(list(map(str.strip, parts)), parts, [ln for _, ln in chunks], size)


def tokenize_lazy(
    chunks: list[tuple[str, int]],
    pdelim: str,
    rdelim: str,
    filename: str,
    *,
    de: int | None = None,
    entity_type: int | None = None,
) -> TokenList | list[Token]:
    """`tokenize`, returning a `TokenList` (tokens made on demand) for plain records."""
    fast = _tokenize_plain("".join(c for c, _ in chunks), chunks, pdelim, rdelim, None)
    if fast is not None:
        return fast
    return tokenize(chunks, pdelim, rdelim, filename, de=de, entity_type=entity_type)


def tokenize(
    chunks: list[tuple[str, int]],
    pdelim: str,
    rdelim: str,
    filename: str,
    *,
    de: int | None = None,
    entity_type: int | None = None,
    max_tokens: int | None = None,
) -> list[Token]:
    """Split free-format text into tokens up to the record delimiter.

    ``chunks`` are (text, line number) pieces joined in order (Global: columns 1-72, Parameter
    Data: columns 1-64). Hollerith strings ``nH...`` may contain delimiters and span lines.
    Raises IgesError if the record delimiter is missing or a Hollerith count runs past the end.
    """
    text = "".join(c for c, _ in chunks)
    fast = _tokenize_plain(text, chunks, pdelim, rdelim, max_tokens)
    if fast is not None:
        return list(fast)
    starts = []
    pos = 0
    for c, ln in chunks:
        starts.append((pos, ln))
        pos += len(c)

    def line_at(k: int) -> int:
        lo, hi = 0, len(starts) - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if starts[mid][0] <= k:
                lo = mid
            else:
                hi = mid - 1
        return starts[lo][1] if starts else 0

    tokens: list[Token] = []
    i, n = 0, len(text)
    while True:
        if max_tokens is not None and len(tokens) > max_tokens:
            raise IgesError(f"more than {max_tokens} parameters", filename=filename, line=line_at(i), de=de,
                            entity_type=entity_type)
        m = _HOLLERITH.match(text, i)
        if m:
            count = int(m.group(1)) if len(m.group(1)) < 10 else n + 1
            s0 = m.end()
            if s0 + count > n:
                raise IgesError(f"Hollerith string of {m.group(1)} characters runs past the end of the record",
                                filename=filename, line=line_at(i), de=de, entity_type=entity_type)
            tokens.append(Token(text[s0 : s0 + count], line_at(s0), True))
            j = s0 + count
            while j < n and text[j] == " ":
                j += 1
            if j >= n:
                raise IgesError("record delimiter missing after a string", filename=filename,
                                line=line_at(n - 1), de=de, entity_type=entity_type)
            ch = text[j]
            if ch == rdelim:
                return tokens
            if ch != pdelim:
                raise IgesError(f"unexpected {ch!r} after a Hollerith string", filename=filename,
                                line=line_at(j), de=de, entity_type=entity_type)
            i = j + 1
            continue
        j_p = text.find(pdelim, i)
        j_r = text.find(rdelim, i)
        if j_r < 0 and j_p < 0:
            raise IgesError(f"record delimiter {rdelim!r} missing (truncated parameters?)", filename=filename,
                            line=line_at(max(n - 1, 0)), de=de, entity_type=entity_type)
        if j_p >= 0 and (j_r < 0 or j_p < j_r):
            tokens.append(Token(text[i:j_p].strip(), line_at(i)))
            i = j_p + 1
        else:
            tokens.append(Token(text[i:j_r].strip(), line_at(i)))
            return tokens
