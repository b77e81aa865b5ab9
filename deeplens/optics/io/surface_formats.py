"""The file-format registry: one handler per surface type reads and writes its records.

A handler (a :class:`SurfaceFormat` subclass) knows, for one deeplens surface type,

* ``zmx_types``: the Zemax ``TYPE`` names it reads (``read_zmx`` builds the surface of one
  ``SURF`` block, :class:`~.zmx_parse.ZmxSurface`, with the block's context :class:`ZmxContext`);
* ``classes``: the deeplens surface classes it writes (``write_zmx`` gives the records of the
  surface after its ``SURF``/``STOP`` lines, up to and with its aperture records);
* ``codev_types``: the CODE V surface-type commands it reads (``read_codev``, with ``codev_data``
  the modifier commands it owns such as ``K`` or ``A``), and ``write_codev`` for its classes.

A handler that does not implement one direction leaves the base method, which refuses with
:class:`NotImplementedError`; the readers and writers ask :meth:`SurfaceFormat.writes_codev`
etc. and refuse with their usual located error.  The writer finds a surface's handler by its
class's method resolution order (the most derived registered class wins: a
:class:`~deeplens.optics.surfaces.Toroid` is written by the handler of
:class:`~deeplens.optics.surfaces.Cylinder` unless one registers ``Toroid`` itself).

A new surface type registers its handler with the :func:`register_format` class decorator in
the module that defines it (the built-in ones: :mod:`.surface_handlers`); a test or a user's
session may register one for a ``with`` block only with :func:`registered_format`, which removes
it again on exit.  :data:`FORMATS` is filled at import and, apart from such a ``with`` block,
never changed afterwards.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

__all__ = ["SurfaceFormat", "FormatRegistry", "FORMATS", "QBFS_CONIC", "ZmxContext",
           "register_format", "registered_format", "refuse_unread", "xdat_term_count",
           "zmx_number", "zmx_diam"]

#: the readings of a ``QED_TYPE`` Qbfs on a conic base (``CONI`` != 0), which no OpticStudio
#: page defines: ``"forbes"`` (default) Forbes' conic generalisation (Opt. Express 19, 9923
#: (2011); optiland's), loaded with one located warning; ``"refuse"`` a located error
QBFS_CONIC = ("forbes", "refuse")


def zmx_number(v) -> str:
    """A number as the ``.zmx`` writers write it: ``repr`` of the float, the shortest text that
    reads back to the same float (a lens written and read again is the same bit for bit)."""
    return repr(float(v))


def refuse_unread(p, records: dict, where: str, why: str, read=(), kind: str = "PARM") -> None:
    """Refuse, at its line, the first record (by number) of a ``SURF`` block's ``records``
    (its ``parm`` or ``xdat``: number -> ``(value, line)``) that is not 0 and whose number is
    not in ``read``: ``"{where} {kind} {i} = {value} is not read ({why})"`` (``where``: the
    surface and its type, ``"SURF 3: EVENASPH"``; ``why``: what the type's records are, or
    why no other is read).  ``p``: the reader's :class:`~.zmx_parse.Locator`."""
    for i, (v, ln) in sorted(records.items()):
        if i not in read and v != 0:
            p.fail(ln, f"{where} {kind} {i} = {v:g} is not read ({why})")


def xdat_term_count(p, s, k, type_name: str, count_what: str, maximum: int, terms: str,
                     below: bool = True) -> int:
    """``XDAT 1`` of surface ``k`` (a ``type_name`` surface): the number of terms, an integer
    ``0..maximum``; no non-zero ``XDAT j`` beyond the ``n + 2`` it declares (nor, with
    ``below``, at ``j < 1``).  Returns ``n``; a bad value fails at its line."""
    n_v, n_ln = s.xdat.get(1, (0.0, s.type_line))
    if n_v != int(n_v) or not 0 <= n_v <= maximum:
        p.fail(n_ln, f"SURF {k}: {type_name} XDAT 1 ({count_what}) must be an integer "
                     f"0..{maximum}, got {n_v!r}")
    n = int(n_v)
    for j, (v, ln) in sorted(s.xdat.items()):
        if (j > n + 2 or (below and j < 1)) and v != 0:
            p.fail(ln, f"SURF {k}: {type_name} XDAT {j} lies beyond the {n} {terms} XDAT 1 "
                       f"declares")
    return n


def zmx_diam(sd) -> str:
    """The ``DIAM`` record of a semi-diameter ``sd`` (mm) the file fixes (flag 1)."""
    return f"DIAM {zmx_number(sd)} 1 0 0 1 \"\""


@dataclass(frozen=True)
class ZmxContext:
    """What :meth:`SurfaceFormat.read_zmx` knows of a ``SURF`` block besides its records.

    Attributes:
        k: the file's surface number (``SURF k``).
        c: the vertex curvature ``CURV`` (1/mm).
        sd: the semi-diameter (mm) from ``DIAM`` or ``CLAP`` (0: none given).
        sd_build: the semi-diameter (mm) to build with (``sd``, or a provisional one when the
            semi-diameter is automatic and set from real rays later).
        s_mm: millimetres per file unit.
        mat: the medium after the surface; ``prev``: the one before it.
        fixed: ``DIAM`` is fixed (flag 1) and positive.
        flat: the handler's :meth:`SurfaceFormat.zmx_flat` answer for the block.
        p: the reader's :class:`~.zmx_parse.Locator` (``p.fail(line, message)``).
        qbfs_conic: how a ``QED_TYPE`` Qbfs on a conic base is read (:data:`QBFS_CONIC`):
            ``"forbes"`` (Forbes' conic generalisation, with a located warning) or
            ``"refuse"``.
    """

    k: int
    c: float
    sd: float
    sd_build: float
    s_mm: float
    mat: object
    prev: object
    fixed: bool
    flat: bool
    p: object
    qbfs_conic: str = "forbes"


class SurfaceFormat:
    """One surface type's records in the Zemax and CODE V files (see the module docstring).

    Class attributes: ``classes`` (deeplens surface classes written), ``zmx_types`` (Zemax
    ``TYPE`` names read), ``codev_types`` (CODE V surface-type commands read), ``codev_data``
    (the CODE V modifier commands this type owns, read by :meth:`codev_modifier`),
    ``shape_only`` (whether every type read is a shape alone: between the same medium on both
    sides it has no refractive power, so OpticStudio applies no floating aperture there and a
    fixed ``DIAM`` does not clip; ideal lenses, phases, gratings and holograms bend rays in air
    and set it ``False``; every reading format states it).
    """

    classes: tuple[type, ...] = ()
    zmx_types: tuple[str, ...] = ()
    shape_only: bool = False
    codev_types: tuple[str, ...] = ()
    codev_data: tuple[str, ...] = ()

    # ---- Zemax
    def zmx_flat(self, s, ctx: ZmxContext) -> bool:
        """Whether block ``s`` is a flat surface (a dummy when it also has no aperture and the
        same medium on both sides); ``ctx.flat`` is not yet set."""
        return False

    def read_zmx(self, s, ctx: ZmxContext):
        """The deeplens surface of ``SURF`` block ``s`` (lengths in ``ctx.s_mm`` per file
        unit); errors through ``ctx.p.fail(line, message)`` or a ``ValueError`` (located on
        the ``TYPE`` line by the caller)."""
        raise NotImplementedError(f"{type(self).__name__} reads no Zemax surface type")

    def write_zmx(self, surface, i: int) -> list[str]:
        """The records of ``surface`` (the lens's surface ``i``) after its ``SURF`` and ``STOP``
        lines: ``TYPE``, ``CURV``, ``CONI``, ``PARM``, ``XDAT``, ``DIAM`` and its aperture records
        (``DISZ`` and ``GLAS`` are the writer's); raises
        :class:`~deeplens.optics.errors.ZemaxFileError` for what has no Zemax record."""
        raise NotImplementedError(f"{type(self).__name__} writes no Zemax surface")

    def writes_zmx(self) -> bool:
        return type(self).write_zmx is not SurfaceFormat.write_zmx

    # ---- CODE V
    def codev_modifier(self, rec: dict, cmd: str, value: float, fail) -> None:
        """Store modifier ``cmd`` (one of :attr:`codev_data`) with its ``value`` on the surface
        record ``rec``; ``fail(message)`` refuses it, located on its line."""
        raise NotImplementedError(f"{type(self).__name__} owns no CODE V modifier")

    def read_codev(self, rec: dict, c: float, sd: float, u: float, flat_air: bool):
        """The deeplens surface of CODE V surface record ``rec`` (its ``type`` one of
        :attr:`codev_types`): ``c`` the curvature (1/mm), ``sd`` the semi-diameter (mm), ``u``
        mm per file unit, ``flat_air`` a flat surface between air on both sides."""
        raise NotImplementedError(f"{type(self).__name__} reads no CODE V surface type")

    def write_codev(self, surface, i: int, stop: bool) -> list[str]:
        """``[curvature, modifier lines ...]`` of ``surface`` (the lens's surface ``i``; ``stop``:
        it is the stop); raises :class:`~deeplens.optics.errors.LensFileError` for what has no
        CODE V equivalent."""
        raise NotImplementedError(f"{type(self).__name__} writes no CODE V surface")

    def writes_codev(self) -> bool:
        return type(self).write_codev is not SurfaceFormat.write_codev


class FormatRegistry:
    """Handlers by Zemax type name, CODE V type command and surface class (see the module
    docstring); a name or class registered twice is refused."""

    def __init__(self):
        self._zmx: dict[str, SurfaceFormat] = {}
        self._codev: dict[str, SurfaceFormat] = {}
        self._classes: dict[type, SurfaceFormat] = {}

    def _tables(self, handler: SurfaceFormat):
        return ((self._zmx, handler.zmx_types, "Zemax type"),
                (self._codev, handler.codev_types, "CODE V type"),
                (self._classes, handler.classes, "surface class"))

    def add(self, handler: SurfaceFormat) -> SurfaceFormat:
        """Register ``handler`` under every name and class it declares.

        Raises:
            ValueError: one of them already has a handler (nothing is registered then).
        """
        for table, keys, what in self._tables(handler):
            for key in keys:
                if key in table:
                    name = key.__name__ if isinstance(key, type) else key
                    raise ValueError(f"{what} {name!r} already has a file handler "
                                     f"({type(table[key]).__name__}); cannot register "
                                     f"{type(handler).__name__}")
        for table, keys, _ in self._tables(handler):
            for key in keys:
                table[key] = handler
        return handler

    def remove(self, handler: SurfaceFormat) -> None:
        """Unregister ``handler`` (every name and class that maps to it)."""
        for table, keys, _ in self._tables(handler):
            for key in keys:
                if table.get(key) is handler:
                    del table[key]

    def zmx_types(self) -> list[str]:
        """The Zemax ``TYPE`` names read, in registration order."""
        return list(self._zmx)

    def codev_types(self) -> list[str]:
        """The CODE V surface-type commands read, in registration order."""
        return list(self._codev)

    def for_zmx_type(self, name: str) -> SurfaceFormat | None:
        return self._zmx.get(name)

    def for_codev_type(self, name: str) -> SurfaceFormat | None:
        return self._codev.get(name)

    def for_surface(self, surface) -> SurfaceFormat | None:
        """The handler of the most derived registered class of ``surface`` (``None``: none)."""
        for cls in type(surface).__mro__:
            h = self._classes.get(cls)
            if h is not None:
                return h
        return None


#: the registry the readers and writers use; filled at import by :func:`register_format`
FORMATS = FormatRegistry()


def register_format(cls: type[SurfaceFormat]) -> type[SurfaceFormat]:
    """Class decorator: register an instance of the handler class ``cls`` in :data:`FORMATS`."""
    FORMATS.add(cls())
    return cls


@contextlib.contextmanager
def registered_format(handler: SurfaceFormat, registry: FormatRegistry = FORMATS):
    """Register ``handler`` for the ``with`` block only (a test's toy surface type, a plug-in
    for one session); it is removed on exit, also when the block raises.

    Example::

        with registered_format(MyFormat()):
            lens = read_zmx("with_my_type.zmx")
    """
    registry.add(handler)
    try:
        yield handler
    finally:
        registry.remove(handler)
