"""Structured errors of the optics layer: what went wrong, and where, as attributes.

Callers decide from the attributes (``surfaces``, ``key``, ``line``), never from the message
text: the table and Zemax readers map ``surfaces`` to their own line numbers, the JSON reader
maps ``key`` to the field path, and the training set-up maps ``key`` to its configuration key.

:class:`ConfigError` is the one error of a configuration value (the Hydra config of training
and evaluation, a tolerance group): it lives here, at the bottom of the package, so that every
room may raise it without an upward import.
"""

from __future__ import annotations

__all__ = ["ConfigError", "LensError", "LensFileError", "SurfacesCrossError", "ZemaxFileError",
           "ZemaxWarning", "format_config_error", "format_lines"]


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
    semi-diameters are only estimates (automatic ones) can limit them there.  Not raised for
    a gap the lens crosses backwards (:attr:`Lens.backward_gaps
    <deeplens.optics.lens.Lens.backward_gaps>`)."""

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
        details: the longer explanation that is not part of the one-line message (e.g. every
            glass catalogue searched for a glass not found), or ``None``; ``deeplens ... -v``
            prints it.
    """

    def __init__(self, message: str, *, source=None, line: int | None = None,
                 feature: str | None = None, surf: int | None = None, surfaces=(),
                 details: str | None = None):
        self.feature = feature
        self.surf = surf
        self.details = details
        super().__init__(message, source=source, line=line, surfaces=surfaces)


class ZemaxWarning(UserWarning):
    """A line of a ``.zmx`` file that was understood but is not used (or a glass that came
    from a catalogue other than the one asked for).

    ``str(warning)`` is ``"SOURCE:LINE: MESSAGE"`` (``MESSAGE`` alone without a line), or, for
    one cause met on several lines, ``"SOURCE:L1,L2,L3: MESSAGE"`` (at most
    :data:`MAX_WARNING_LINES` lines named, then ``"and N more"``); the parts are attributes:
    ``message``, ``source``, ``line`` (the first line; ``None`` when no single line is
    concerned), ``lines`` (every line, in order; ``()`` without one) and ``feature`` (the first
    line's record keyword, or ``None``).
    """

    def __init__(self, message: str, *, source=None, line: int | None = None,
                 feature: str | None = None, lines=()):
        self.message = message
        self.source = None if source is None else str(source)
        self.lines = tuple(int(v) for v in lines) or ((line,) if line else ())
        self.line = self.lines[0] if self.lines else line
        self.feature = feature
        where = f"{self.source}:{format_lines(self.lines)}" if self.source and self.lines else ""
        super().__init__(f"{where}: {message}" if where else message)


#: the most lines a :class:`ZemaxWarning`'s location names (the rest counted)
MAX_WARNING_LINES = 6


def format_lines(lines) -> str:
    """``"87,93,101"``: the lines of one warning, the first :data:`MAX_WARNING_LINES` named and
    the rest counted (``"1,2,3,4,5,6 and 10 more"``)."""
    lines = list(lines)
    shown = ",".join(str(v) for v in lines[:MAX_WARNING_LINES])
    more = len(lines) - MAX_WARNING_LINES
    return f"{shown} and {more} more" if more > 0 else shown


def format_config_error(key: str, expected: str, got, kind: str = "value",
                        source: str | None = None) -> str:
    """The one message format of a bad configuration value (:class:`ConfigError`):

    * ``kind="value"``: ``"{key}: expected {expected}, got {got!r}"``;
    * ``kind="missing"``: ``"{key}: missing; expected {expected}"`` (``got`` unused);
    * ``kind="unknown"``: ``"{key}: unknown key(s) {got}; expected some of {expected}"``
      (``got``: the sorted unknown keys, ``expected``: the known ones);

    prefixed by ``"{source}: "`` when the value came from a file (a tolerance group's YAML).
    """
    if kind == "missing":
        text = f"{key}: missing; expected {expected}"
    elif kind == "unknown":
        text = f"{key}: unknown key(s) {got}; expected some of {expected}"
    else:
        text = f"{key}: expected {expected}, got {got!r}"
    return f"{source}: {text}" if source else text


class ConfigError(ValueError):
    """A configuration value that cannot be used (a wrong type, a value out of range, an
    unknown or a missing key).  ``str(error)`` is :func:`format_config_error`'s, the only place
    the message is written; callers read the attributes, never the text.

    Attributes:
        key: the full dotted config key, e.g. ``"model.deconvolution.nsr"`` (a mapping's own
            key for ``kind="unknown"``, e.g. ``"model.loss"``).
        expected: what was expected, in words (``kind="unknown"``: the known keys).
        got: the value received (``kind="unknown"``: the sorted unknown keys; ``kind="missing"``:
            ``None``).
        kind: ``"value"``, ``"missing"`` or ``"unknown"``.
        source: the file the value came from, or ``None``.

    Build one with ``ConfigError(key, expected, got)``, :meth:`missing` or :meth:`unknown`.
    """

    def __init__(self, key: str, expected: str, got=None, *, kind: str = "value",
                 source=None):
        if kind not in ("value", "missing", "unknown"):
            raise ValueError(f"ConfigError: kind must be value, missing or unknown, got {kind!r}")
        self.key, self.expected, self.got, self.kind = str(key), str(expected), got, kind
        self.source = None if source is None else str(source)
        super().__init__(format_config_error(self.key, self.expected, got, kind, self.source))

    @classmethod
    def missing(cls, key: str, expected: str, source=None) -> "ConfigError":
        """``key`` is absent (or null where a value is needed)."""
        return cls(key, expected, None, kind="missing", source=source)

    @classmethod
    def unknown(cls, key: str, unknown, known, source=None) -> "ConfigError":
        """The mapping ``key`` holds keys it does not know: ``unknown`` (listed sorted) of
        ``known`` (listed in their own order)."""
        return cls(key, str(list(known)), sorted(str(k) for k in unknown), kind="unknown",
                   source=source)

    def with_source(self, source) -> "ConfigError":
        """The same error, naming the file the value came from."""
        return ConfigError(self.key, self.expected, self.got, kind=self.kind, source=source)

    def __reduce__(self):  # picklable (a fan-out job's error crosses processes)
        return (_rebuild_config_error, (self.key, self.expected, self.got, self.kind,
                                        self.source))


def _rebuild_config_error(key, expected, got, kind, source) -> ConfigError:
    return ConfigError(key, expected, got, kind=kind, source=source)
