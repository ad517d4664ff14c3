"""Fixed-format IGES records: split a file into its S, G, D, P, T sections, and tokenise
free-format parameter text (Global and Parameter Data sections).

A *record* is one 80-column line: columns 1-72 data, column 73 the section letter,
columns 74-80 the sequence number. Every token keeps the file line number it starts on,
so any later error can point at the line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from cadbridge.iges.errors import IgesError

__all__ = ["Record", "Sections", "Token", "split_sections", "tokenize"]

SECTION_ORDER = "SGDPT"


@dataclass(frozen=True)
class Record:
    """One line of a section: ``text`` is columns 1-72 (padded to 72), ``line`` the 1-based
    line number in the file, ``seq`` the sequence number from columns 74-80."""

    text: str
    line: int
    seq: int


@dataclass
class Sections:
    """The records of each section, in file order, plus reader notes (line, message)."""

    start: list[Record] = field(default_factory=list)
    global_: list[Record] = field(default_factory=list)
    directory: list[Record] = field(default_factory=list)
    parameter: list[Record] = field(default_factory=list)
    terminate: list[Record] = field(default_factory=list)
    notes: list[tuple[int, str]] = field(default_factory=list)


def _lines(text: str) -> list[str]:
    lines = text.splitlines()
    # files written as one long string of 80-column records (no line breaks)
    if len(lines) == 1 and len(lines[0]) > 80 and len(lines[0]) % 80 == 0:
        s = lines[0]
        lines = [s[i : i + 80] for i in range(0, len(s), 80)]
    return lines


def split_sections(text: str, filename: str) -> Sections:
    """Split file text into sections, checking section letters, order and sequence numbers.

    Raises IgesError for compressed/binary files, unknown section letters, sections out of
    order, broken sequence numbers, or an empty file. A missing T section is only noted.
    """
    if "\x00" in text[:4096]:
        raise IgesError("binary IGES is not supported (NUL bytes found)", filename=filename, line=1)
    lines = _lines(text)
    secs = Sections()
    by_letter = {"S": secs.start, "G": secs.global_, "D": secs.directory, "P": secs.parameter, "T": secs.terminate}
    current = -1
    for i, raw in enumerate(lines, start=1):
        s = raw.rstrip("\r\n\x1a")
        if not s.strip():
            if any(l.strip() for l in lines[i:]):
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


@dataclass(frozen=True)
class Token:
    """One free-format parameter: ``text`` stripped of blanks (the characters of a Hollerith
    string, without ``nH``, when ``is_string``), ``line`` the file line it starts on."""

    text: str
    line: int
    is_string: bool = False


_HOLLERITH = re.compile(r"\s*(\d+)[Hh]")


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
