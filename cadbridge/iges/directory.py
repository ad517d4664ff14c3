"""Directory Entry section: two 80-column lines per entity, twenty 8-character fields."""

from __future__ import annotations

from dataclasses import dataclass

from cadbridge.iges.errors import IgesError
from cadbridge.iges.lexer import Record

__all__ = ["DirectoryEntry", "parse_directory"]


@dataclass(frozen=True)
class DirectoryEntry:
    """One directory entry (IGES 5.3 section 2.2.4.4). ``de`` is its sequence number (odd)."""

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


def parse_directory(records: list[Record], filename: str) -> dict[int, DirectoryEntry]:
    """Parse D records (even count checked by the lexer) into {DE number: DirectoryEntry}."""
    out: dict[int, DirectoryEntry] = {}
    for k in range(0, len(records), 2):
        r1, r2 = records[k], records[k + 1]
        de = r1.seq
        t1, t2 = r1.text, r2.text
        etype = _int_field(t1, 0, r1, de, "entity type", filename)
        etype2 = _int_field(t2, 0, r2, de, "entity type (line 2)", filename, etype)
        if etype2 != etype:
            raise IgesError(f"entity type {etype} on the first line of the entry but {etype2} on the second",
                            filename=filename, line=r2.line, de=de, entity_type=etype, field="entity type")
        vals = [_int_field(t1, j, r1, de, name, filename, etype) for j, name in enumerate(
            ["entity type", "parameter data", "structure", "line font", "level", "view",
             "transformation matrix", "label display"])]
        status = t1[64:72].strip()
        if status and not status.isdigit():
            raise IgesError(f"status number {status!r} is not 8 digits", filename=filename, line=r1.line,
                            de=de, entity_type=etype, field="status number")
        status = status.zfill(8)
        lw = _int_field(t2, 1, r2, de, "line weight", filename, etype)
        color = _int_field(t2, 2, r2, de, "color", filename, etype)
        pcount = _int_field(t2, 3, r2, de, "parameter line count", filename, etype)
        form = _int_field(t2, 4, r2, de, "form", filename, etype)
        label = t2[56:64].strip()
        sub = _int_field(t2, 8, r2, de, "entity subscript", filename, etype)
        if vals[1] <= 0 and etype != 0:
            raise IgesError(f"parameter data pointer {vals[1]} must be positive", filename=filename,
                            line=r1.line, de=de, entity_type=etype, field="parameter data")
        if pcount < 0:
            raise IgesError(f"parameter line count {pcount} is negative", filename=filename, line=r2.line,
                            de=de, entity_type=etype, field="parameter line count")
        out[de] = DirectoryEntry(
            de=de, entity_type=etype, param_pointer=vals[1], structure=vals[2], line_font=vals[3],
            level=vals[4], view=vals[5], transform=vals[6], label_display=vals[7],
            blank_status=int(status[0:2]), subordinate=int(status[2:4]), entity_use=int(status[4:6]),
            hierarchy=int(status[6:8]), line_weight=lw, color=color, param_count=pcount, form=form,
            label=label, subscript=sub, line=r1.line,
        )
    return out
