"""The Global section (IGES 5.3 section 2.2.4): delimiters, units, resolution, names."""

from __future__ import annotations

from dataclasses import dataclass, field

from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record, Token, tokenize
from cadbridge.iges.values import parse_int, parse_real
from cadbridge.cad.model import Units

__all__ = ["GlobalSection", "parse_global", "units_from_flag", "UNIT_TABLE"]

# IGES units flag -> (name, millimetres per unit)   (5.3 Table 3)
UNIT_TABLE: dict[int, tuple[str, float]] = {
    1: ("IN", 25.4),
    2: ("MM", 1.0),
    4: ("FT", 304.8),
    5: ("MI", 1609344.0),
    6: ("M", 1000.0),
    7: ("KM", 1000000.0),
    8: ("MIL", 0.0254),
    9: ("UM", 0.001),
    10: ("CM", 10.0),
    11: ("UIN", 0.0000254),
}
_NAME_TO_FLAG = {"INCH": 1, "INCHES": 1, "IN": 1, "MM": 2, "FT": 4, "MI": 5, "M": 6, "KM": 7, "MIL": 8,
                 "UM": 9, "MICRON": 9, "CM": 10, "UIN": 11}

# 1-based Global field numbers (IGES 5.3)
F_PRODUCT_ID, F_FILE_NAME, F_SYSTEM, F_PREPROCESSOR = 3, 4, 5, 6
F_UNITS_FLAG, F_UNITS_NAME, F_RESOLUTION, F_AUTHOR, F_ORGANIZATION = 14, 15, 19, 21, 22


@dataclass
class GlobalSection:
    """Parsed Global section. ``values[k]`` is field k+1 converted (str for strings, else the
    raw token text); ``lines[k]`` its file line."""

    pdelim: str = ","
    rdelim: str = ";"
    values: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    units: Units = field(default_factory=Units)
    resolution: float | None = None
    notes: list = field(default_factory=list)  # (line, message)

    def string(self, k: int) -> str | None:
        """Field k (1-based) as a string, None when absent/empty."""
        if k - 1 < len(self.values):
            v = self.values[k - 1]
            if isinstance(v, str) and v != "":
                return v
        return None


def units_from_flag(flag: int, name: str | None) -> Units:
    """`Units` for an IGES units flag (3 = use the name). Unknown → ValueError."""
    if flag == 3:
        key = (name or "").strip().upper().replace("'", "")
        if key not in _NAME_TO_FLAG:
            raise ValueError(f"units flag 3 with unknown units name {name!r}")
        base = UNIT_TABLE[_NAME_TO_FLAG[key]]
        return Units(3, name.strip(), base[1])
    if flag not in UNIT_TABLE:
        raise ValueError(f"unknown units flag {flag}")
    nm, mm = UNIT_TABLE[flag]
    return Units(flag, (name or nm).strip() or nm, mm)


def parse_global(records: list[Record], filename: str) -> GlobalSection:
    """Parse the Global section records (columns 1-72). Raises IgesError on bad fields."""
    g = GlobalSection()
    chunks = [(r.text, r.line) for r in records]
    text = "".join(c for c, _ in chunks)
    first = records[0].line
    # Field 1: parameter delimiter. Either empty (',' default: text starts with the default
    # delimiter) or '1Hx' followed by the new delimiter x (or a ',').
    i = 0
    while i < len(text) and text[i] == " ":
        i += 1
    pdelim = ","
    if text.startswith(("1H", "1h"), i):
        pdelim = text[i + 2]
        i += 3
        if i >= len(text) or text[i] not in (pdelim, ","):
            raise IgesError(f"Global field 1: expected a delimiter after 1H{pdelim}", filename=filename,
                            line=first, field="parameter delimiter")
        sep = text[i]
        i += 1
    elif text[i : i + 1] == ",":
        sep = ","
        i += 1
    elif text[i : i + 1] == ";":  # an empty Global section
        g.notes.append((first, "empty Global section: defaults used"))
        return g
    else:
        raise IgesError(f"Global field 1 (parameter delimiter) must be empty or 1Hx, got {text[i:i+8]!r}",
                        filename=filename, line=first, field="parameter delimiter")
    # Field 2: record delimiter
    rdelim = ";"
    while i < len(text) and text[i] == " ":
        i += 1
    if text.startswith(("1H", "1h"), i):
        rdelim = text[i + 2]
        i += 3
    if pdelim == rdelim or pdelim in " 0123456789+-.HDE" or rdelim in " 0123456789+-.HDE":
        raise IgesError(f"invalid delimiters {pdelim!r} / {rdelim!r}", filename=filename, line=first,
                        field="record delimiter")
    g.pdelim, g.rdelim = pdelim, rdelim
    rest_text = text[i:]
    if rest_text[:1] == rdelim:
        g.values = [pdelim, rdelim]
        g.lines = [first, first]
        return g
    if rest_text[:1] not in (pdelim, sep):
        raise IgesError(f"Global field 2: expected a delimiter, got {rest_text[:8]!r}", filename=filename,
                        line=first, field="record delimiter")
    # Tokenise the rest, keeping lines: rebuild chunks from offset i+1
    off = i + 1
    rest: list[tuple[str, int]] = []
    pos = 0
    for c, ln in chunks:
        a, b = pos, pos + len(c)
        if b > off:
            rest.append((c[max(0, off - a) :], ln))
        pos = b
    toks = tokenize(rest, pdelim, rdelim, filename, max_tokens=1000) if rest else []
    g.values = [pdelim, rdelim] + [t.text for t in toks]
    g.lines = [first, first] + [t.line for t in toks]
    tok_by_field = {k + 3: t for k, t in enumerate(toks)}

    def tok(k: int) -> Token | None:
        return tok_by_field.get(k)

    flag_tok = tok(F_UNITS_FLAG)
    name_tok = tok(F_UNITS_NAME)
    name = name_tok.text if (name_tok is not None and name_tok.is_string) else None
    try:
        flag = parse_int(flag_tok, 2) if flag_tok is not None else 2
    except ValueError as e:
        raise IgesError(str(e), filename=filename, line=flag_tok.line, field="units flag (G14)") from None
    try:
        g.units = units_from_flag(flag, name)
    except ValueError as e:
        line = flag_tok.line if flag_tok is not None else first
        raise IgesError(str(e), filename=filename, line=line, field="units flag (G14)") from None
    if flag != 3 and name and name.strip().upper() in _NAME_TO_FLAG and _NAME_TO_FLAG[name.strip().upper()] != flag:
        g.notes.append((flag_tok.line if flag_tok is not None else first,
                        f"units flag {flag} ({g.units.name}) disagrees with units name {name!r}: flag used"))
        g.units = units_from_flag(flag, None)
    res_tok = tok(F_RESOLUTION)
    if res_tok is not None and res_tok.text:
        try:
            g.resolution = parse_real(res_tok)
        except ValueError as e:
            raise IgesError(str(e), filename=filename, line=res_tok.line, field="resolution (G19)") from None
    return g
