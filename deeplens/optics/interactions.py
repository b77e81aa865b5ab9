"""What a surface does to a ray: the interaction a surface holds (its *law*).

The tracer (:meth:`Lens.trace_surface <deeplens.optics.lens.Lens.trace_surface>`) intersects
a surface and then hands the hit to ``surface.interaction``; it never asks the surface's class.
Each interaction is a small stateless object that declares what the tracer may do with it:

* ``name`` (``surface.law``): ``"refract"``, ``"ideal"``, ``"diffract"``, ``"stop"``,
  ``"frame"``;
* ``lands``: the rays land on the surface (a stop is crossed, not landed on; a frame change
  is not a surface at all);
* ``changes_frame``: the surface re-expresses the rays in the next frame (a coordinate break);
* ``reflects``: the surface may be a mirror (``Lens(mirrors=...)``);
* ``fusable``: the law after the hit is Snell's law (or a stop's clip), which the closed-form
  quadric step and the fused compiled kernels apply themselves (:mod:`.compiled`);
* ``same_medium``: the medium must not change across it (a stop).

Calling an interaction that ``lands`` applies it at the hits:
``interaction(surface, x, d, n1, n2, wavelength, valid, opl, mirror) -> (d, valid, opl)``
with ``x`` ``(*B, 3)`` the hits in the surface's local frame (mm), ``d`` ``(*B, 3)`` the unit
directions, ``n1``, ``n2`` the indices before and after (broadcastable to ``(*B,)``),
``wavelength`` (nm), ``valid`` ``(*B,)``, ``opl`` ``(*B,)`` the optical path so far (mm) and
``mirror`` whether the lens makes the surface reflect.  A new law is one class here (or in the
surface's own file) and one attribute on the surface: ``interaction = MyLaw()``.
"""

from __future__ import annotations

from .reflect import reflect
from .refract import refract

__all__ = ["Interaction", "Refraction", "Reflection", "IdealDeflection", "Diffraction",
           "StopCrossing", "FrameChange", "REFRACTION", "REFLECTION", "IDEAL_DEFLECTION",
           "DIFFRACTION", "STOP_CROSSING", "FRAME_CHANGE"]


class Interaction:
    """Base class: the declared capabilities (module docstring); ``__call__`` applies it."""

    name = "interaction"
    lands = True
    changes_frame = False
    reflects = True
    fusable = False
    same_medium = False

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class Reflection(Interaction):
    """The law of reflection at the surface's normal (:func:`~.reflect.reflect`)."""

    name = "reflect"
    fusable = True

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        d, valid = reflect(d, surface.normal(x), valid)
        return d, valid, opl


class Refraction(Interaction):
    """Vector Snell's law at the surface's normal (:func:`~.refract.refract`), ``n1 / n2``; a
    mirror reflects instead (:class:`Reflection`)."""

    name = "refract"
    fusable = True

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        if mirror:
            return REFLECTION(surface, x, d, n1, n2, wavelength, valid, opl, mirror)
        d, valid = refract(d, surface.normal(x), n1 / n2, valid)
        return d, valid, opl


class IdealDeflection(Interaction):
    """A perfect thin lens: ``surface.deflect(x, d, valid)`` maps the direction tangents
    (:class:`~.surfaces.IdealLens`); no optical path is added, never a mirror."""

    name = "ideal"
    reflects = False

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        d, valid = surface.deflect(x, d, valid)
        return d, valid, opl


class Diffraction(Interaction):
    """A diffractive surface (:class:`~.surfaces.Grating`, :class:`~.surfaces.Binary2`): the
    bare surface's refraction (reflection at a mirror), then its order,
    ``surface.diffract(x, d, wavelength, n_after, valid)``, with ``n_after`` the index the ray
    leaves into, and its phase in the optical path, ``surface.phase_opl(x, wavelength)``."""

    name = "diffract"

    def __call__(self, surface, x, d, n1, n2, wavelength, valid, opl, mirror: bool):
        d, valid, opl = REFRACTION(surface, x, d, n1, n2, wavelength, valid, opl, mirror)
        d, valid = surface.diffract(x, d, wavelength, n1 if mirror else n2, valid)
        return d, valid, opl + surface.phase_opl(x, wavelength)


class StopCrossing(Interaction):
    """An aperture stop: crossed, not landed on (:meth:`Lens._cross_stop
    <deeplens.optics.lens.Lens._cross_stop>` clips where each ray's line crosses it by the
    surface's opening); the medium is the same on both sides; the fused kernels clip it
    (its opening's :attr:`~.openings.Opening.fused` kind)."""

    name = "stop"
    lands = False
    reflects = False
    fusable = True
    same_medium = True


class FrameChange(Interaction):
    """A coordinate break: the rays are re-expressed in the next frame
    (``surface.to_next``/``to_previous``), nothing else."""

    name = "frame"
    lands = False
    changes_frame = True
    reflects = False


#: the shared instances the surfaces hold (the interactions are stateless)
REFRACTION = Refraction()
REFLECTION = Reflection()
IDEAL_DEFLECTION = IdealDeflection()
DIFFRACTION = Diffraction()
STOP_CROSSING = StopCrossing()
FRAME_CHANGE = FrameChange()
