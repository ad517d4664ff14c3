"""`IgesError`: every problem in an IGES file, located by file, line, DE, entity and field."""

from __future__ import annotations

__all__ = ["IgesError"]


class IgesError(ValueError):
    """A malformed or unsupported IGES file.

    Attributes ``filename``, ``line`` (1-based line number in the file), ``de`` (directory
    entry sequence number), ``entity_type`` and ``field`` (IGES field name, e.g. ``"K1"``)
    are None when unknown. ``str()`` gives e.g.
    ``die.igs line 57 (DE 13, entity 128, field K1): expected an integer, got 'x'``.
    """

    def __init__(
        self,
        message: str,
        *,
        filename: str | None = None,
        line: int | None = None,
        de: int | None = None,
        entity_type: int | None = None,
        field: str | None = None,
    ) -> None:
        self.message = message
        self.filename = filename
        self.line = line
        self.de = de
        self.entity_type = entity_type
        self.field = field
        super().__init__(self._format())

    def _format(self) -> str:
        head = self.filename or "<iges>"
        if self.line is not None:
            head += f" line {self.line}"
        ctx = []
        if self.de is not None:
            ctx.append(f"DE {self.de}")
        if self.entity_type is not None:
            ctx.append(f"entity {self.entity_type}")
        if self.field is not None:
            ctx.append(f"field {self.field}")
        if ctx:
            head += " (" + ", ".join(ctx) + ")"
        return f"{head}: {self.message}"

    def __str__(self) -> str:
        return self._format()

    def __reduce__(self):  # keep the keyword attributes through pickling
        return (_rebuild, (self.message, self.filename, self.line, self.de, self.entity_type, self.field))


def _rebuild(message, filename, line, de, entity_type, field) -> IgesError:
    return IgesError(message, filename=filename, line=line, de=de, entity_type=entity_type, field=field)
