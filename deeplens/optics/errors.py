"""Structured errors of the optics layer: what went wrong, and where, as attributes.

Callers decide from the attributes (``surfaces``, ``key``, ``line``), never from the message
text: the table and Zemax readers map ``surfaces`` to their own line numbers, the JSON reader
maps ``key`` to the field path, and the training set-up maps ``key`` to its configuration key.
"""

from __future__ import annotations

__all__ = ["LensError", "SurfacesCrossError", "LensFileError", "ZemaxFileError", "ZemaxWarning"]


class LensError(ValueError):
    """An inconsistent lens prescription.

    Attributes:
        message: the explanation (also ``str(error)``).
        surfaces: indices of the surfaces concerned (``()`` when none).
        key: the quantity concerned when it is not a surface, e.g. ``"sensor"``, ``"stop"``,
            ``"fields_deg"``, ``"aperture"``, ``"object_distance_mm"`` (``None`` otherwise).
    """

    def __init__(self, message: str, *, surfaces=(), key: str | None = None):
        super().__init__(message)
        self.message = message
        self.surfaces = tuple(int(i) for i in surfaces)
        self.key = key


class SurfacesCrossError(LensError):
    """Two consecutive surfaces that cross within their semi-diameters (a negative edge
    thickness): a :class:`LensError` whose ``surfaces`` are the pair ``(i, j)`` and whose
    ``radius`` is the smallest radius (mm) at which they meet, so that a reader whose
    semi-diameters are only estimates (automatic ones) can limit them there."""

    def __init__(self, message: str, *, surfaces, radius: float):
        super().__init__(message, surfaces=surfaces)
        self.radius = float(radius)


class LensFileError(ValueError):
    """A lens file (or reader option) that cannot be used.

    ``str(error)`` is ``"SOURCE[:LINE[:COLUMN]]: [KEY: ]MESSAGE"``; the parts are attributes:

    Attributes:
        message: the explanation.
        source: the file (or ``"<dict>"``), ``None`` when the message already names it.
        key: the JSON path of the field (``"surfaces[3].b"``) or the reader option
            (``"stop_index"``), ``None`` when no single field is at fault.
        line, column: the position in a text file, or ``None``.
        surfaces: indices of the surfaces concerned (``()`` when none).
    """

    def __init__(self, message: str, *, source=None, key: str | None = None,
                 line: int | None = None, column: int | None = None, surfaces=()):
        self.message = message
        self.column = column
        self.source = None if source is None else str(source)
        self.key = key
        self.line = line
        self.surfaces = tuple(int(i) for i in surfaces)
        super().__init__(self._format())

    def _format(self) -> str:
        where = self.source or ""
        if where and self.line is not None:
            where = f"{where}:{self.line}"
            if self.column is not None:
                where = f"{where}:{self.column}"
        return ": ".join(p for p in (where, self.key, self.message) if p)


class ZemaxFileError(LensFileError):
    """A ``.zmx`` file that cannot be read (or a lens that cannot be written as one).

    ``str(error)`` is ``"SOURCE[:LINE]: MESSAGE"`` (as :class:`LensFileError`); the location is
    also in attributes, which callers read instead of parsing the message:

    Attributes:
        source: the ``.zmx`` file (``None`` for a lens the writer cannot express).
        line: the 1-based line of the record at fault (``None`` when no single line is).
        feature: the keyword of that record (``"CLAP"``, ``"TYPE"``, ``"GLAS"``, ...), or
            ``None``.
        surf: the file's surface number (``SURF n``) whose block holds that line, or ``None``.
        surfaces: deeplens' surface indices concerned (``()`` when none).
    """

    def __init__(self, message: str, *, source=None, line: int | None = None,
                 feature: str | None = None, surf: int | None = None, surfaces=()):
        self.feature = feature
        self.surf = surf
        super().__init__(message, source=source, line=line, surfaces=surfaces)


class ZemaxWarning(UserWarning):
    """A line of a ``.zmx`` file that was understood but is not used (or a glass that came
    from a catalogue other than the one asked for).

    ``str(warning)`` is ``"SOURCE:LINE: MESSAGE"`` (``MESSAGE`` alone without a line); the parts
    are attributes: ``message``, ``source``, ``line`` (``None`` when no single line is concerned)
    and ``feature`` (the record's keyword, or ``None``).
    """

    def __init__(self, message: str, *, source=None, line: int | None = None,
                 feature: str | None = None):
        self.message = message
        self.source = None if source is None else str(source)
        self.line = line
        self.feature = feature
        where = f"{self.source}:{line}" if self.source and line else ""
        super().__init__(f"{where}: {message}" if where else message)
