"""Aperture stop: an opaque plane ``z = 0`` with a circular or rectangular opening.

Circular: a ray passes if ``x^2 + y^2 <= r^2`` (``r`` = semi-diameter); with a central
obscuration of radius ``r_o`` (an annular opening), only if also ``x^2 + y^2 >= r_o^2``; with a
ring obscuration ``r_i <= ρ <= r_o`` (a ring baffle, Zemax's ``OBSC r_i r_o``, ``r_i > 0``), if
``x^2 + y^2 >= r_o^2`` or ``x^2 + y^2 <= r_i^2`` (both circles' rims pass).
Rectangular: it passes if ``|x| <= w_x`` and ``|y| <= w_y`` (half-widths in mm).
Elliptical: it passes if ``(x / a)^2 + (y / b)^2 <= 1`` (half-axes ``a = w_x``, ``b = w_y`` in mm,
held in the same ``half_widths`` buffer; Zemax's ``ELAP``, CODE V's ``ELX``/``ELY``).
An elliptical obscuration of half-axes ``(a_o, b_o)`` (Zemax's ``ELOB`` on a flat surface in
air) takes out ``(x / a_o)^2 + (y / b_o)^2 < 1`` of a circular opening (its rim passes).
A decentred opening (``decenter = (d_x, d_y)``, mm; Zemax's ``OBDC``) is the same test on
``(x − d_x, y − d_y)``: the opening and its obscuration move together; the plane does not.
The medium does not change across a stop.

A stop is *crossed, not landed on* (a virtual stop, :meth:`Lens._cross_stop
<deeplens.optics.lens.Lens._cross_stop>`): the test is made where each ray's line crosses the
plane, ahead of the ray or behind it, and the ray goes on to the next surface from where it
was, so a stop may lie inside a neighbouring lens's sag (a negative distance before or after
it, as phone-lens prescriptions place it).
"""

from __future__ import annotations

import math

import torch

from ..interactions import STOP_CROSSING
from ..openings import Circle, Ellipse, Opening, Rectangle, Spider, in_rect
from .base import host_flags, register_surface
from .plane import Plane

__all__ = ["Aperture", "in_rect"]


@register_surface("aperture")
class Aperture(Plane):
    """An aperture stop plane.

    Args:
        semi_diameter: radius of a circular opening, mm (for a rectangle: its half-diagonal
            is used as semi-diameter when not given).
        shape: ``"circle"``, ``"rect"`` or ``"ellipse"``.
        half_width_x, half_width_y: half-widths of a rectangular opening, or half-axes (along
            x, along y) of an elliptical one, mm.
        obscuration: radius of a central obscuration of a circular opening, mm (``0``: none;
            ``< semi_diameter``); with ``obscuration_inner``, the ring's outer radius, which
            may lie at or beyond ``semi_diameter`` (the opening is then the disc inside
            ``obscuration_inner``, or the whole circle where the ring lies beyond it).
        obscuration_inner: the inner radius of a ring obscuration, mm (``0``: the obscuration
            is central; else ``0 < obscuration_inner < obscuration``): rays pass inside it and
            outside ``obscuration``.
        obscuration_ellipse: ``(a_o, b_o)``, mm, or ``None``: an elliptical obscuration of these
            half-axes (along x, along y) in a circular opening, instead of a circular one; both
            below ``semi_diameter``.  A fixed buffer ``obscuration_ellipse``, registered only
            when given (not in ``state_dict``; lens file: ``obscuration_ellipse_mm``).
        spider: ``(width, n_arms, angle)`` or ``None``: a spider obscuration in a circular
            opening without another obscuration (:class:`~deeplens.optics.openings.Spider`:
            ``n_arms`` equally spaced arms of full width ``width`` mm from the centre, the first
            at ``angle`` radians from +x towards +y; Zemax's ``SPID``).  A fixed buffer
            ``spider``, registered only when given (not in ``state_dict``; lens file:
            ``spider_width_mm``, ``spider_arms``, ``spider_angle_deg``); traced eager.
        decenter: ``(d_x, d_y)``, mm: the centre of the opening (and of its obscuration) in the
            plane; ``(0, 0)`` by default.  A decentred aperture runs eager (the compiled runs
            clip about the axis).
    """

    #: crossed, not landed on (:meth:`Lens._cross_stop <deeplens.optics.lens.Lens._cross_stop>`)
    interaction = STOP_CROSSING

    def __init__(self, semi_diameter: float | None = None, shape: str = "circle",
                 half_width_x: float | None = None, half_width_y: float | None = None,
                 obscuration: float = 0.0, decenter: tuple[float, float] = (0.0, 0.0),
                 obscuration_inner: float = 0.0, obscuration_ellipse=None, spider=None):
        if shape not in ("circle", "rect", "ellipse"):
            raise ValueError(f"Aperture: shape must be 'circle', 'rect' or 'ellipse', got "
                             f"{shape!r}")
        if shape != "circle":
            what = "rectangular" if shape == "rect" else "elliptical"
            if half_width_x is None or half_width_y is None:
                raise ValueError(f"Aperture: a {what} aperture needs half_width_x and "
                                 f"half_width_y (mm)")
            if not (0 < half_width_x < math.inf and 0 < half_width_y < math.inf):
                raise ValueError(f"Aperture: half-widths must be finite and > 0 mm, got "
                                 f"{half_width_x}, {half_width_y}")
            if semi_diameter is None:   # the circumscribed circle
                semi_diameter = ((half_width_x ** 2 + half_width_y ** 2) ** 0.5 if shape == "rect"
                                 else max(half_width_x, half_width_y))
        if semi_diameter is None:
            raise ValueError("Aperture: a circular aperture needs semi_diameter (mm)")
        super().__init__(semi_diameter)
        self.shape = shape
        hw = [half_width_x or 0.0, half_width_y or 0.0]
        self.register_buffer("half_widths", torch.tensor(hw, dtype=torch.float64))
        obscuration = float(obscuration)
        ri = float(obscuration_inner)
        # a ring (ri > 0) may reach past the rim (OpticStudio allows a surface aperture beyond
        # the semi-diameter): the opening is then the disc inside ri, or the whole circle when
        # the ring lies beyond it; a central obscuration at or past the rim would block all
        if obscuration != 0.0 and (shape != "circle" or not 0 < obscuration < math.inf or (
                ri == 0.0 and not obscuration < float(semi_diameter))):
            raise ValueError(f"Aperture: a central obscuration needs a circular opening and "
                             f"0 < radius < semi_diameter ({float(semi_diameter):g} mm), got "
                             f"{obscuration!r}")
        self.register_buffer("obscuration", torch.tensor(obscuration, dtype=torch.float64))
        if ri != 0.0 and not 0 < ri < obscuration:
            raise ValueError(f"Aperture: a ring obscuration needs 0 < inner radius < the "
                             f"obscuration's radius ({obscuration:g} mm), got "
                             f"{obscuration_inner!r}")
        # not in state_dict (as before rings existed: checkpoints keep their keys); it comes
        # with the lens file (obscuration_inner_mm)
        self.register_buffer("obscuration_inner", torch.tensor(ri, dtype=torch.float64),
                             persistent=False)
        if obscuration_ellipse is not None:
            ab = [float(v) for v in obscuration_ellipse]
            if (len(ab) != 2 or shape != "circle" or obscuration != 0.0
                    or not all(0 < v < float(semi_diameter) for v in ab)):
                raise ValueError(f"Aperture: an elliptical obscuration needs a circular opening "
                                 f"without a circular obscuration and two half-axes > 0 and "
                                 f"below semi_diameter ({float(semi_diameter):g} mm), got "
                                 f"{obscuration_ellipse!r}")
            self.register_buffer("obscuration_ellipse", torch.tensor(ab, dtype=torch.float64),
                                 persistent=False)
        if spider is not None:
            vals = list(spider)
            if (len(vals) != 3 or shape != "circle" or obscuration != 0.0
                    or obscuration_ellipse is not None):
                raise ValueError(f"Aperture: a spider needs a circular opening without another "
                                 f"obscuration and (width mm, n_arms, angle rad), got {spider!r}")
            w, n, ang = float(vals[0]), vals[1], float(vals[2])
            Spider(w, n, ang)   # validates: width > 0, n an integer >= 1, a finite angle
            self.register_buffer("spider", torch.tensor([w, int(n), ang], dtype=torch.float64),
                                 persistent=False)
        self._n_spider = 0 if spider is None else int(spider[1])   # host int: no sync at clips
        dec = [float(v) for v in decenter]
        if len(dec) != 2 or not all(math.isfinite(v) for v in dec):
            raise ValueError(f"Aperture: decenter must be two finite numbers of mm (d_x, d_y), "
                             f"got {decenter!r}")
        self.register_buffer("decenter", torch.tensor(dec, dtype=torch.float64))

    @property
    def decentred(self) -> bool:
        """Whether the opening's centre is off the axis."""
        return bool((self.decenter != 0).any())

    def _build_opening(self) -> Opening:
        """The circle (semi-diameter) or rectangle (half-widths) about the decenter, less the
        obscuration's circle about the same centre."""
        decentred, obscured, ring = host_flags(
            self, "_opening_flags", (self.decenter, self.obscuration, self.obscuration_inner),
            lambda dec, obs, ri: (bool((dec != 0).any()), float(obs) > 0, float(ri) > 0))
        dec = self.decenter if decentred else None
        outer = (Rectangle(self.half_widths, dec, check=False) if self.shape == "rect"
                 else Ellipse(self.half_widths, dec, check=False) if self.shape == "ellipse"
                 else Circle(self.semi_diameter, dec, check=False))
        if ring:   # the ring r_i <= ρ <= r_o is taken out; inside r_i passes
            return outer - (Circle(self.obscuration, dec, check=False)
                            - Circle(self.obscuration_inner, dec, check=False))
        if obscured:
            return outer - Circle(self.obscuration, dec, check=False)
        ell = self._buffers.get("obscuration_ellipse")   # present only when set
        if ell is not None:
            return outer - Ellipse(ell, dec, check=False)
        spi = self._buffers.get("spider")   # present only when set: (width, n_arms, angle)
        if spi is not None:
            return outer - Spider(spi[0], self.n_spider_arms, spi[2], dec, check=False)
        return outer

    @property
    def n_spider_arms(self) -> int:
        """The spider's number of arms (0: no spider), a Python int."""
        return self._n_spider

    def spider_of(self):
        """``(width mm, n_arms, angle rad)`` of the spider, or ``None``."""
        spi = self._buffers.get("spider")
        return None if spi is None else (float(spi[0]), self.n_spider_arms, float(spi[2]))

    @property
    def fused(self) -> str | None:
        """``"stop"`` or ``"stop_rect"``: the fused kernels clip by the opening's centred circle
        or rectangle (:attr:`~deeplens.optics.openings.Opening.kernel_clip`, also the values,
        :meth:`fused_values`); ``None`` (eager) for an annular or decentred opening."""
        clip = self.opening.kernel_clip
        if clip is None:
            return None
        return "stop_rect" if clip[0] == "rect" else "stop"

    def set_semi_diameter(self, value: float) -> None:
        """Resize a circular stop (used when the aperture is given as EPD or F-number)."""
        self.semi_diameter.fill_(float(value))

    file_fields = ("shape", "half_width_x_mm", "half_width_y_mm", "obscuration_mm",
                   "obscuration_inner_mm", "decenter_mm", "obscuration_ellipse_mm",
                   "spider_width_mm", "spider_arms", "spider_angle_deg")

    @classmethod
    def from_dict(cls, entry, semi_diameter):
        shape = entry.get("shape", "str", default="circle")
        if shape not in ("circle", "rect", "ellipse"):
            entry.fail("shape", f"expected 'circle', 'rect' or 'ellipse', got {shape!r}")
        dec = entry.get("decenter_mm", "numbers", default=[0.0, 0.0])
        if len(dec) != 2:
            entry.fail("decenter_mm", f"expected [d_x, d_y] in mm, got {dec!r}")
        if shape != "circle":
            return cls(semi_diameter, shape, entry.get("half_width_x_mm"),
                       entry.get("half_width_y_mm"), decenter=dec)
        ell = entry.get("obscuration_ellipse_mm", "numbers", default=None)
        if ell is not None and len(ell) != 2:
            entry.fail("obscuration_ellipse_mm", f"expected [a, b] in mm (half-axes along x and "
                                                 f"y), got {ell!r}")
        spider = None
        width = entry.get("spider_width_mm", default=None)
        if width is not None:
            n = entry.get("spider_arms", default=None)
            if n is None or int(n) != n or n < 1:
                entry.fail("spider_arms", f"expected the spider's number of arms, an integer "
                                          f">= 1, beside spider_width_mm, got {n!r}")
            if not width > 0:
                entry.fail("spider_width_mm", f"expected the arms' full width > 0 mm, got "
                                              f"{width!r}")
            spider = (width, int(n), math.radians(entry.get("spider_angle_deg", default=0.0)))
        elif entry.get("spider_arms", default=None) is not None:
            entry.fail("spider_arms", "a spider needs spider_width_mm (the arms' full width)")
        return cls(semi_diameter, shape, obscuration=entry.get("obscuration_mm", default=0.0),
                   decenter=dec,
                   obscuration_inner=entry.get("obscuration_inner_mm", default=0.0),
                   obscuration_ellipse=ell, spider=spider)

    def to_dict(self) -> dict:
        d = super().to_dict()
        if float(self.obscuration) > 0:
            d["obscuration_mm"] = float(self.obscuration)
        if float(self.obscuration_inner) > 0:
            d["obscuration_inner_mm"] = float(self.obscuration_inner)
        ell = self._buffers.get("obscuration_ellipse")
        if ell is not None:
            d["obscuration_ellipse_mm"] = [float(v) for v in ell]
        spi = self.spider_of()
        if spi is not None:
            d.update(spider_width_mm=spi[0], spider_arms=spi[1])
            if spi[2] != 0.0:
                d["spider_angle_deg"] = math.degrees(spi[2])
        if self.shape != "circle":
            d.update(shape=self.shape, half_width_x_mm=float(self.half_widths[0]),
                     half_width_y_mm=float(self.half_widths[1]))
        if self.decentred:
            d["decenter_mm"] = [float(v) for v in self.decenter]
        return d
