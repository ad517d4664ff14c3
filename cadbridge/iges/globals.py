"""The Global section (IGES 5.3 section 2.2.4): delimiters, units, resolution, names."""

from __future__ import annotations

from dataclasses import dataclass, field

from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record, Token, tokenize
from cadbridge.iges.values import parse_int, parse_real
from cadbridge.cad.model import Units

__all__ = ["GlobalSection", "parse_global", "units_from_flag", "resolve_units", "UNIT_TABLE"]

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


def _unit_name(name: str | None) -> int | None:
    """The units flag a G15 units name stands for (IGES 5.3 2.2.4.3.15), None if none."""
    return _NAME_TO_FLAG.get((name or "").strip().upper().replace("'", ""))


def resolve_units(flag: int | None, name: str | None) -> tuple[Units, str | None]:
    """The length unit of units flag G14 (None: field omitted) and units name G15, with a
    note when it is not simply the flag's (IGES 5.3 2.2.4.3.14-15: flag 1..11, 3 = the unit
    named by G15; omitted flag = 1, inches). Raises ValueError ``(message, field)`` when
    the unit is undefined: flag 3 without a known name, or a flag outside 1..11 without one."""
    named = _unit_name(name)
    if flag == 3 or (flag is not None and flag not in UNIT_TABLE):
        if named is None:
            what = f"units name (G15) {name.strip()!r} is no IGES 5.3 unit name" if (name or "").strip() else \
                "units name (G15) is empty"
            if flag == 3:
                raise ValueError(f"units flag (G14) = 3 names the unit by G15, but {what}: the length unit is "
                                 f"undefined", "units name (G15)")
            raise ValueError(f"units flag (G14) = {flag} is not an IGES 5.3 value (1..11) and {what}: the length "
                             f"unit is undefined", "units flag (G14)")
        units = Units(3 if flag == 3 else named, name.strip(), UNIT_TABLE[named][1])
        note = None if flag == 3 else f"units flag (G14) = {flag} is not an IGES 5.3 value (1..11): the unit named " \
            f"by G15, {name.strip()!r}, used"
        return units, note
    if flag is None:
        if named is not None:
            return Units(named, name.strip(), UNIT_TABLE[named][1]), f"units flag (G14) omitted: the unit named by " \
                f"G15, {name.strip()!r}, used"
        return units_from_flag(1, None), "units flag (G14) and name (G15) omitted: IGES 5.3 default 1 (inches) used"
    return units_from_flag(flag, name), None


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
        g.units, note = resolve_units(None, None)
        g.notes.append((first, f"empty Global section: defaults used ({note})"))
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
        g.units, note = resolve_units(None, None)
        g.notes.append((first, note))
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
        flag = parse_int(flag_tok) if flag_tok is not None and flag_tok.text else None
    except ValueError as e:
        raise IgesError(str(e), filename=filename, line=flag_tok.line, field="units flag (G14)") from None
    try:
        g.units, note = resolve_units(flag, name)
    except ValueError as e:
        msg, fld = e.args
        tok_ = name_tok if fld.startswith("units name") and name_tok is not None else flag_tok
        raise IgesError(msg, filename=filename, line=tok_.line if tok_ is not None else first, field=fld) from None
    if note:
        g.notes.append((flag_tok.line if flag_tok is not None else first, note))
    if flag in UNIT_TABLE and name and name.strip().upper() in _NAME_TO_FLAG and _NAME_TO_FLAG[name.strip().upper()] != flag:
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
