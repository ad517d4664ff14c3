"""Directory Entry section: two 80-column lines per entity, twenty 8-character fields."""

from __future__ import annotations

from typing import NamedTuple
from operator import itemgetter

from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record

__all__ = ["DirectoryEntry", "parse_directory"]


class DirectoryEntry(NamedTuple):
    """One directory entry (IGES 5.3 section 2.2.4.4). ``de`` is its sequence number (odd).
    (An immutable named tuple: cheaper to build than a 20-field frozen dataclass.)"""

    de: int
    entity_type: int  # field 1
    param_pointer: int  # field 2: first P line
    structure: int  # field 3
    line_font: int  # field 4
    level: int  # field 5
    view: int  # field 6
    transform: int  # field 7: DE of a 124, or 0
    label_display: int  # field 8
    blank_status: int  # field 9, digits 1-2
    subordinate: int  # field 9, digits 3-4: 0 independent, 1 physically, 2 logically, 3 both
    entity_use: int  # field 9, digits 5-6
    hierarchy: int  # field 9, digits 7-8
    line_weight: int  # field 12
    color: int  # field 13: 0-8 standard colour, negative = -(DE of a 314)
    param_count: int  # field 14: number of P lines
    form: int  # field 15
    label: str  # field 18
    subscript: int  # field 19
    line: int  # file line of the first of the two records

    @property
    def physically_dependent(self) -> bool:
        """Subordinate switch 01 or 03: the entity exists only as part of another."""
        return self.subordinate in (1, 3)


def _int_field(text: str, k: int, rec: Record, de: int, name: str, filename: str, etype=None) -> int:
    s = text[8 * k : 8 * k + 8].strip()
    if not s:
        return 0
    try:
        return int(s)
    except ValueError:
        raise IgesError(f"directory field {name} is not an integer: {s!r}", filename=filename,
                        line=rec.line, de=de, entity_type=etype, field=name) from None


_FIELDS_1 = itemgetter(*(slice(8 * j, 8 * j + 8) for j in range(8)))  # line 1, fields 1-8
_FIELDS_2 = itemgetter(*(slice(8 * j, 8 * j + 8) for j in (0, 1, 2, 3, 4, 8)))  # line 2: 11-15, 19


def _ints(fields: tuple[str, ...]) -> list[int]:
    """Integer fields, blank = 0 (raises ValueError like `_int_field` would)."""
    try:
        return list(map(int, fields))  # usual case: no blank field
    except ValueError:
        return [0 if f.isspace() or not f else int(f) for f in fields]


def parse_directory(records: list[Record], filename: str) -> dict[int, DirectoryEntry]:
    """Parse D records (even count checked by the lexer) into {DE number: DirectoryEntry}."""
    out: dict[int, DirectoryEntry] = {}
    for k in range(0, len(records), 2):
        r1, r2 = records[k], records[k + 1]
        de = r1.seq
        t1, t2 = r1.text, r2.text
        # fast path: every integer field readable (int() strips blanks as `_int_field` does);
        # otherwise the field-by-field path below finds the first bad field and reports it
        try:
            vals = _ints(_FIELDS_1(t1))
            etype2, lw, color, pcount, form, sub = _ints(_FIELDS_2(t2))
            etype = vals[0]
            slow = False
        except ValueError:
            slow = True
            etype = _int_field(t1, 0, r1, de, "entity type", filename)
            etype2 = _int_field(t2, 0, r2, de, "entity type (line 2)", filename, etype)
            vals = None
        if etype2 != etype:
            raise IgesError(f"entity type {etype} on the first line of the entry but {etype2} on the second",
                            filename=filename, line=r2.line, de=de, entity_type=etype, field="entity type")
        if vals is None:
            vals = [_int_field(t1, j, r1, de, name, filename, etype) for j, name in enumerate(
                ["entity type", "parameter data", "structure", "line font", "level", "view",
                 "transformation matrix", "label display"])]
        status = t1[64:72].strip()
        if status and not status.isdigit():
            raise IgesError(f"status number {status!r} is not 8 digits", filename=filename, line=r1.line,
                            de=de, entity_type=etype, field="status number")
        status = status.zfill(8)
        if slow:
            lw = _int_field(t2, 1, r2, de, "line weight", filename, etype)
            color = _int_field(t2, 2, r2, de, "color", filename, etype)
            pcount = _int_field(t2, 3, r2, de, "parameter line count", filename, etype)
            form = _int_field(t2, 4, r2, de, "form", filename, etype)
        label = t2[56:64].strip()
        if slow:
            sub = _int_field(t2, 8, r2, de, "entity subscript", filename, etype)
        if vals[1] <= 0 and etype != 0:
            raise IgesError(f"parameter data pointer {vals[1]} must be positive", filename=filename,
                            line=r1.line, de=de, entity_type=etype, field="parameter data")
        if pcount < 0:
            raise IgesError(f"parameter line count {pcount} is negative", filename=filename, line=r2.line,
                            de=de, entity_type=etype, field="parameter line count")
        out[de] = DirectoryEntry(  # positional, in field order (faster than keywords)
            de, etype, vals[1], vals[2], vals[3], vals[4], vals[5], vals[6], vals[7],
            int(status[0:2]), int(status[2:4]), int(status[4:6]), int(status[6:8]),
            lw, color, pcount, form, label, sub, r1.line,
        )
    return out
