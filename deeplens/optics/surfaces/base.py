"""The surface interface: an implicit function ``f(x, y, z; θ) = 0`` in the surface's local frame.

Every surface lives in a local frame whose origin is its vertex and whose ``z`` axis is the
optical axis.  A surface provides

* ``f(x, y, z)``         the implicit function (mm); for a sag surface ``f = sag(x, y) - z``
* ``f_grad(x, y, z)``    ``(∂f/∂x, ∂f/∂y, ∂f/∂z)``, analytic, differentiable in ``θ``
* ``in_domain(x, y)``    where ``f`` is defined (e.g. inside a conic's sqrt domain)
* ``in_aperture(x, y)``  inside the surface's ``opening`` (:mod:`..openings`; the
  semi-diameter's circle by default)
* ``sag(x, y)``          the surface height, for layouts and crossing checks
* ``paraxial_curvature`` the vertex curvature used by paraxial analysis (1/mm)

What happens after the hit is the surface's ``interaction`` (:mod:`..interactions`), how it
runs compiled its ``fused_geometry``/``fused_values``, and the natural scale of each of its
parameters its ``sag_scale``: the tracer and :mod:`..parameters` ask these, never the class.

Serialisation: each type registers its lens-file ``type`` name with :func:`register_surface`
and owns both directions: ``to_dict()`` writes its entry, ``from_dict(entry, semi_diameter)``
reads it back through a small reader interface (``entry.get(key, kind, default)``,
``entry.has(key)``, ``entry.fail(key, message)``) that the file reader implements, so every
registered type can be read as soon as it can be written.  ``file_fields`` lists its own keys.

The normal is ``∇f/|∇f|``.  Prescription values are ``nn.Parameter`` objects created with
``requires_grad=False``; make any one of them trainable with ``p.requires_grad_(True)``.
Implementations must stay finite (never NaN or inf, also in their derivatives) for *any* finite
input, including points outside their domain: the tracer evaluates them on invalid rays too and
masks the result, and a NaN in a masked branch would still poison gradients.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..interactions import REFRACTION
from ..openings import (Circle, Difference, Ellipse, Intersection, Opening, Rectangle, Spider,
                        in_circle)
from ..refract import unit_normal

__all__ = ["Surface", "SagSurface", "in_circle", "make_param", "SURFACE_TYPES", "register_surface",
           "set_clear_rect", "clear_rect_of", "takes_clear_rect", "set_clear_ellipse",
           "clear_ellipse_of", "set_obscuration_ellipse", "obscuration_ellipse_of",
           "set_obscuration_spider", "obscuration_spider_of",
           "curvature_scale", "conic_scale", "in_closed_domain"]

#: lens-file ``type`` name (and aliases) -> surface class; filled by :func:`register_surface`
#: at import and read by the lens-file reader and writer (never changed afterwards)
SURFACE_TYPES: dict[str, type] = {}


def register_surface(name: str, aliases: tuple[str, ...] = ()):
    """Class decorator: register a surface type under its lens-file ``type`` name (and aliases
    the reader also accepts); the writer uses ``name``."""

    def deco(cls):
        cls.type_name = name
        for key in (name, *aliases):
            if key in SURFACE_TYPES:
                raise ValueError(f"surface type {key!r} is registered twice "
                                 f"({SURFACE_TYPES[key].__name__} and {cls.__name__})")
            SURFACE_TYPES[key] = cls
        return cls

    return deco


#: the rim band of a conic's domain, in rounding units: an argument ``1 - (1+k) c^2 r^2`` from 0
#: down to ``-CONIC_RIM_EPS eps`` is the rim itself (:func:`check_conic_domain`, float64's eps:
#: the file's numbers; :func:`~.asphere.conic_root`, 0 there, the points' dtype's eps)
CONIC_RIM_EPS = 8.0


def check_conic_domain(sd: float, c: float, k: float, what: str, where: str = "") -> None:
    """Raise ``ValueError`` when the semi-diameter ``sd`` (mm) lies beyond the domain of a
    conic of curvature ``c`` (1/mm) and conic constant ``k``: its sag is defined only for
    ``r^2 (1 + k) c^2 < 1``.  ``what`` names the conic in the message (``"conic"``,
    ``"Q-type surface's conic base"``, ...).

    A semi-diameter *on* the rim of the domain is accepted: a full hemisphere (``sd = |R|``,
    a ball lens's face) or an ellipsoid to its equator.  "On" within the rounding of the
    numbers: ``c`` and ``sd`` as read from a file carry up to one rounding each from the
    decimal number and one from a unit scaling (``|δc/c|, |δsd/sd| <= eps``, ``eps = 2^-52``),
    the product ``c sd`` one more half (``2.5 eps``), its square twice that, ``(1 + k)`` and
    the products ``1.5 eps`` more: ``|1 - (1+k) c² sd²| <= 6.5 eps`` at the true rim, so an
    argument down to ``-8 eps`` (``CONIC_RIM_EPS``; ``sd`` at most ``4 eps`` relative beyond
    the rim) is the rim.  The rim itself is outside the domain (the slope is infinite there):
    the tracer marks a ray that lands exactly on it invalid, as it does any ray outside a
    surface's domain, and rays inside are traced (a grazing incidence near the rim)."""
    if 1.0 - (1.0 + k) * c * c * sd * sd < -CONIC_RIM_EPS * 2.0 ** -52:
        limit = (1.0 / ((1.0 + k) * c * c)) ** 0.5
        raise ValueError(f"{where}semi-diameter {sd:g} mm lies beyond the domain of the {what} "
                         f"(R = {1 / c:g} mm, k = {k:g}): the sag is only defined for "
                         f"r < {limit:g} mm")


def in_closed_domain(surface, x, y):
    """``surface.in_domain`` at ``(x, y)`` pulled towards the axis by ``CONIC_RIM_EPS / 2`` (4)
    float64 rounding units: a point on the rim of a conic's domain counts (a hemisphere's rim
    ``r = |R|``, where the sag is exact, :func:`~.asphere.conic_root`; the argument
    ``1 - (1+k) c² r²`` grows by ``CONIC_RIM_EPS`` (8) eps, the rim band of
    :func:`check_conic_domain`).  For drawings and crossing checks, where the
    rim of a ball lens's faces is where they meet; the tracer's hits keep ``in_domain`` (a ray
    landing exactly on the rim, at grazing incidence, is invalid)."""
    q = 1.0 - 0.5 * CONIC_RIM_EPS * 2.0 ** -52
    return surface.in_domain(x * q, y * q)


def curvature_scale(R: float) -> float:
    """The scale of a curvature (1/mm) on a surface of semi-diameter ``R`` (mm): ``R^2 / 2``,
    mm of sag at the rim per 1/mm (the derivative of ``c R^2 / (1 + sqrt(1 - (1+k) c^2 R^2))``
    at ``c = 0``; within ``(1+k) c^2 R^2`` of it at the current curvature)."""
    return R * R / 2


def conic_scale(c: float, k: float, R: float) -> float:
    """The scale of a conic constant: ``∂z/∂k = c^3 R^4 / (2 q (1 + q)^2)`` at the rim ``R``
    (mm), ``q = sqrt(1 - (1+k) c^2 R^2)``; 1 for a flat base (``c = 0``: the conic does not
    change the sag) or a rim beyond the conic's domain, and at least 1e-6."""
    arg = 1.0 - (1.0 + k) * c * c * R * R
    if c == 0.0 or arg <= 0.0:
        return 1.0
    q = math.sqrt(arg)
    return max(abs(c) ** 3 * R ** 4 / (2.0 * q * (1.0 + q) ** 2), 1e-6)


def conic_polynomial_scale(surface, name: str, power=None) -> float:
    """The parameter scale of a conic base plus polynomial terms (``surface`` has ``c``, ``k``
    and ``semi_diameter``): ``c``: :func:`curvature_scale`; ``k``: :func:`conic_scale`;
    ``a.i``: ``R^power(i)`` (the term's power of the radius at the rim; ``power=None``: the
    surface has no ``a``); any other name: 1."""
    R, parts = float(surface.semi_diameter), name.split(".")
    if parts[0] == "c":
        return curvature_scale(R)
    if parts[0] == "k":
        return conic_scale(float(surface.c), float(surface.k), R)
    if parts[0] == "a" and power is not None:
        return R ** power(int(parts[1]))
    return 1.0


def host_flags(module: nn.Module, slot: str, tensors: tuple, read):
    """``read(*tensors)`` (Python values read from the tensors: host synchronisations), kept on
    ``module`` under ``slot`` and read again only when one of ``tensors`` changed: another
    tensor object (``.to()``, a buffer assigned anew) or an in-place change (its version
    counter: ``copy_``, ``fill_``, ``load_state_dict``).  The cache holds the tensors
    themselves, so that a freed tensor's ``id`` cannot be taken for a live one.  A surface
    builds its :attr:`~Surface.opening` at every clip from such flags (an obscuration's
    ``> 0``, a clear radius's finiteness): read once, not at every trace.  Inference tensors
    (no version counter) are read every time."""
    try:
        versions = tuple(t._version for t in tensors)
    except RuntimeError:   # an inference tensor: no version counter
        return read(*tensors)
    cached = module.__dict__.get(slot)
    if (cached is not None and cached[1] == versions
            and all(a is b for a, b in zip(cached[0], tensors))):
        return cached[2]
    value = read(*tensors)
    module.__dict__[slot] = (tensors, versions, value)
    return value


def make_param(value, name: str = "value") -> nn.Parameter:
    """A float64 ``nn.Parameter`` that is frozen until the user unfreezes it."""
    t = torch.as_tensor(value, dtype=torch.float64)
    if not torch.isfinite(t).all():
        raise ValueError(f"{name} must be finite, got {value!r}")
    return nn.Parameter(t.clone(), requires_grad=False)


def norm_radius_mm(value, owner: str) -> float:
    """A normalisation radius (mm) as a float: ``ValueError`` naming ``owner`` unless it is a
    finite number ``> 0`` (the surfaces whose terms are in ``x / R_n``, ``y / R_n``)."""
    rn = float(value)
    if not (rn > 0 and math.isfinite(rn)):
        raise ValueError(f"{owner}: the normalisation radius must be a positive number of mm, "
                         f"got {value!r}")
    return rn


class Surface(nn.Module):
    """Base class of all surfaces (see the module docstring).

    Args:
        semi_diameter: clear semi-aperture in mm (``> 0``).
    """

    type_name = "surface"
    #: lens-file fields of this type besides type, distance_mm, semi_diameter_mm and material
    file_fields: tuple[str, ...] = ()
    #: a flat surface is intersected in closed form (no Newton iterations)
    is_flat = False
    #: what happens after the hit (:mod:`~deeplens.optics.interactions`): the tracer asks it
    #: and its declared flags, never the surface's class
    interaction = REFRACTION
    #: the compiled geometry of this type when its law and opening allow a fused run
    #: (:attr:`fused`): ``"plane"``, ``"quadric"``, ``"newton"`` or ``None`` (eager)
    fused_geometry: str | None = None

    def __init__(self, semi_diameter: float):
        super().__init__()
        sd = float(semi_diameter)
        if not (sd > 0 and math.isfinite(sd)):
            raise ValueError(f"{type(self).__name__}: semi_diameter must be a positive number "
                             f"of mm, got {semi_diameter!r}")
        self.register_buffer("semi_diameter", torch.tensor(sd, dtype=torch.float64))

    # ---- the implicit function -------------------------------------------------------
    def f(self, x, y, z):
        raise NotImplementedError

    def f_grad(self, x, y, z):
        raise NotImplementedError

    def in_domain(self, x, y):
        return torch.ones_like(x, dtype=torch.bool)

    # ---- the opening (deeplens.optics.openings) --------------------------------------
    _opening: Opening | None = None

    @property
    def opening(self) -> Opening:
        """Where the surface lets rays through (:mod:`~deeplens.optics.openings`): an opening
        assigned to it (``surface.opening = Circle(3.0) - Circle(1.0)``), else the one its type
        builds from its own values (:meth:`_build_opening`: the semi-diameter's circle by
        default; the obscuration, clear radius, decenter and rectangle of the types that carry
        them, which stay buffers under their lens-file names so that ``state_dict`` and lens
        files do not change)."""
        return self._opening if self._opening is not None else self._build_opening()

    @opening.setter
    def opening(self, value: Opening) -> None:
        if not isinstance(value, Opening):
            raise TypeError(f"{type(self).__name__}.opening: expected an Opening "
                            f"(deeplens.optics.openings), got {type(value).__name__}")
        self._opening = value

    def _build_opening(self) -> Opening:
        """The semi-diameter's circle, and the rectangle of :func:`set_clear_rect` or the
        ellipse of :func:`set_clear_ellipse` when set, less the elliptical obscuration of
        :func:`set_obscuration_ellipse` (each tested at the hit point's local ``x, y``, whatever
        the surface's shape)."""
        opening = Circle(self.semi_diameter, check=False)
        rect = self._buffers.get("clear_rect")
        if rect is not None and bool(rect.any()):
            opening = opening & Rectangle(rect, self._buffers["clear_decenter"], check=False)
        return with_ellipses(self, opening)

    def in_aperture(self, x, y):
        """``(*B,)`` bool: ``(x, y)`` (mm, local frame) lies in the :attr:`opening`."""
        return self.opening.contains(x, y)

    def sag(self, x, y):
        raise NotImplementedError

    #: True when :meth:`quadric` describes the whole surface (closed-form intersection)
    is_quadric = False

    def quadric(self, o, d):
        """``(A, B, C, c', c)`` of a quadric base surface (see :class:`~.asphere.Asphere`), or
        ``None``: the tracer then starts Newton from the vertex plane."""
        return None

    def normal(self, x):
        """Unit normal ``∇f / |∇f|`` ``(*B, 3)`` at points ``x`` ``(*B, 3)``."""
        return unit_normal(*self.f_grad(x[..., 0], x[..., 1], x[..., 2]))

    # ---- the compiled Newton kernels (deeplens.optics.compiled) ---------------------------
    #: A surface type joins the compiled Newton path by defining, in its own file,
    #: ``kernel_values(like)`` (its values in the rays' dtype, or ``None``), and the static
    #: methods ``kernel_f(x, y, z, values) -> (f, f_x, f_y, f_z)``,
    #: ``kernel_in_domain(x, y, values)`` and ``kernel_start(bx, by, bz, dx, dy, dz, ok, values,
    #: root_fn)`` (Newton's start ``s`` from the vertex-plane point), built from the same
    #: functions its ``f``/``f_grad``/``in_domain`` call.  A subclass that changes ``f`` must
    #: redefine them, and declare ``fused_geometry = "newton"``.  Without them the surface runs
    #: eager between compiled runs.
    def kernel_values(self, like):
        return None

    def paraxial_curvature(self) -> torch.Tensor:
        return torch.zeros((), dtype=self.semi_diameter.dtype, device=self.semi_diameter.device)

    # ---- declared capabilities (asked by the tracer, :mod:`deeplens.optics.tracer`) ------
    @property
    def law(self) -> str:
        """The name of :attr:`interaction` (``"refract"``, ``"ideal"``, ``"diffract"``,
        ``"stop"``, ``"frame"``)."""
        return self.interaction.name

    @property
    def diffracts(self) -> bool:
        """The surface diffracts (its law is :class:`~deeplens.optics.interactions.Diffraction`)."""
        return self.interaction.name == "diffract"

    def _plain_opening(self) -> bool:
        """Whether the opening is one centred circle (the closed-form and fused kernels clip
        by nothing else, :attr:`~deeplens.optics.openings.Opening.kernel_clip`)."""
        clip = self.opening.kernel_clip
        return clip is not None and clip[0] == "circle"

    @property
    def closed_form(self) -> bool:
        """The eager tracer may intersect and refract the surface in closed form
        (:func:`~deeplens.optics.intersect.trace_quadric`): a quadric with a fusable law
        (Snell's) and a plain circular opening."""
        return self.is_quadric and self.interaction.fusable and self.interaction.lands \
            and self._plain_opening()

    @property
    def fused(self) -> str | None:
        """The :data:`~deeplens.optics.compiled.KINDS` entry (or ``"newton"``) this surface runs
        as in a compiled trace when its element is aligned, or ``None`` (eager): its
        :attr:`fused_geometry` when its law is fusable and its opening is the plain circle."""
        if not (self.interaction.fusable and self._plain_opening()):
            return None
        return self.fused_geometry

    def fused_values(self, like) -> tuple:
        """The values the fused kind takes (:data:`~deeplens.optics.compiled.KINDS`, after
        ``z_shift``), in ``like``'s dtype: the opening's clip radius by default (the
        semi-diameter unless another opening was assigned)."""
        return (self.opening.kernel_clip[1].to(like),)

    @property
    def radius(self) -> float:
        """Paraxial radius of curvature ``1 / c`` in mm, ``inf`` for a flat vertex (beside the
        curvature ``c`` that the surface stores and optimises)."""
        c = float(self.paraxial_curvature())
        return math.inf if c == 0.0 else 1.0 / c

    def check(self, where: str = "") -> None:
        """Raise ``ValueError`` if the prescription is inconsistent (e.g. aperture beyond domain)."""

    # ---- the natural scale of each parameter (deeplens.optics.parameters) ----------------
    def sag_scale(self, name: str) -> float:
        """mm of sag at the rim (``r = R``, the semi-diameter) per unit of this surface's
        parameter ``name`` (as in ``named_parameters()``, relative to the surface: ``"c"``,
        ``"a.3"``): the design optimiser's and the training step's scale
        (:func:`~deeplens.optics.parameters.parameter_scale`).  Each type gives its own
        (:func:`curvature_scale`, :func:`conic_scale`, ``R^n`` for a coefficient of ``r^n``);
        the default, 1, is for values already in mm and for parameters that do not move the
        sag (a phase, a focal length, a frame change)."""
        return 1.0

    # ---- serialisation ----------------------------------------------------------------
    def to_dict(self) -> dict:
        """Prescription as plain floats (the lens-file ``surfaces[i]`` entry, without spacing);
        :meth:`from_dict` reads it back."""
        return {"type": self.type_name, "semi_diameter_mm": float(self.semi_diameter)}

    @classmethod
    def from_dict(cls, entry, semi_diameter: float) -> "Surface":
        """Build from a lens-file entry (see the module docstring for ``entry``); the common
        fields (distance, semi-diameter, material) are read by the caller."""
        return cls(semi_diameter)

    def extra_repr(self) -> str:
        return f"semi_diameter={float(self.semi_diameter.detach()):.6g} mm"


class SagSurface(Surface):
    """A surface given by a height ``z = sag(x, y)``; ``f = sag - z``.

    Subclasses implement ``sag`` and ``sag_grad`` (returning ``(∂z/∂x, ∂z/∂y)``).  Like any
    surface rays land on, a sag surface can carry a rectangular clear aperture
    (:func:`set_clear_rect`: Zemax's ``SQAP``), which its :attr:`opening` intersects with the
    semi-diameter's circle.
    """

    def sag_grad(self, x, y):
        raise NotImplementedError

    def f(self, x, y, z):
        return self.sag(x, y) - z

    def f_grad(self, x, y, z):
        sx, sy = self.sag_grad(x, y)
        return sx, sy, -torch.ones_like(z)


def takes_clear_rect(surface_or_type) -> bool:
    """Whether :func:`set_clear_rect` applies to this surface (or surface class): any surface
    the rays land on (its interaction ``lands``: a sag surface, an implicit one such as
    :class:`~.xy_polynomial.XYPolynomial`), since the rectangle is tested at the hit point's
    local ``x, y`` (:meth:`Surface.in_aperture`), not on the sag; not a stop or a frame change
    (:class:`~.aperture.Aperture` has its own rectangle, a coordinate break no opening)."""
    cls = surface_or_type if isinstance(surface_or_type, type) else type(surface_or_type)
    return issubclass(cls, Surface) and bool(cls.interaction.lands)


def set_clear_rect(surface: Surface, half_widths) -> None:
    """Give ``surface`` a rectangular clear aperture of half-widths ``(h_x, h_y)`` (mm) about its
    vertex (Zemax's ``SQAP`` on a lens or mirror surface of any type, a tilted plane's
    included): rays meeting it at local ``|x| > h_x`` or ``|y| > h_y`` are blocked.  The opening is the rectangle within its
    circumscribed circle: the clear radius and the semi-diameter become the half-diagonal.
    Fixed buffers, not saved in ``state_dict`` (they come with the lens file,
    ``clear_rect_mm``); a surface with one traces on the generic (eager) path, whose clipping
    asks the surface."""
    if not takes_clear_rect(surface):
        raise TypeError(f"a rectangular clear aperture needs a surface the rays land on (not a "
                        f"stop or a frame change), got {type(surface).__name__}")
    hx, hy = (float(v) for v in half_widths)
    if not (0 < hx < math.inf and 0 < hy < math.inf):
        raise ValueError(f"{type(surface).__name__}: clear_rect must be two half-widths > 0 mm, "
                         f"got {half_widths!r}")
    rect = torch.tensor([hx, hy], dtype=torch.float64)
    diag = math.hypot(hx, hy)
    with torch.no_grad():
        _set_buffer(surface, "clear_rect", rect)
        _set_buffer(surface, "clear_radius", torch.tensor(diag, dtype=torch.float64))
        _keep_decenter(surface)
        surface.semi_diameter.fill_(diag)


def with_ellipses(surface, opening: Opening) -> Opening:
    """``opening`` with ``surface``'s elliptical clear aperture (:func:`set_clear_ellipse`,
    about its ``clear_decenter``) intersected and its elliptical obscuration
    (:func:`set_obscuration_ellipse`, about the vertex) taken out: the part of every lens or
    mirror surface's :meth:`~Surface._build_opening` that the ellipses add.  The buffers exist
    only once set, so their presence is the flag (no host read)."""
    ell = surface._buffers.get("clear_ellipse")
    if ell is not None:
        opening = opening & Ellipse(ell, surface._buffers["clear_decenter"], check=False)
    obs = surface._buffers.get("obscuration_ellipse")
    if obs is not None:
        opening = opening - Ellipse(obs, check=False)
    spi = surface._buffers.get("obscuration_spider")   # (width, n_arms, angle): set_obscuration_spider
    if spi is not None:
        opening = opening - Spider(spi[0], surface._spider_arms, spi[2], check=False)
    return opening


def _has_ellipse(opening: Opening, what) -> bool:
    """Whether ``opening`` holds an :class:`Ellipse` made from the tensor ``what`` (or, for
    ``what`` a spider's buffer, any :class:`Spider`)."""
    if isinstance(opening, Ellipse):
        return opening.half_axes is what
    if isinstance(opening, Spider):
        return what.numel() == 3
    if isinstance(opening, Intersection):
        return any(_has_ellipse(p, what) for p in opening.parts)
    if isinstance(opening, Difference):
        return _has_ellipse(opening.a, what) or _has_ellipse(opening.b, what)
    return False


def _half_axes(surface, half_axes, what: str) -> tuple[float, float]:
    if not takes_clear_rect(surface):
        raise TypeError(f"an elliptical {what} needs a surface the rays land on (not a stop or a "
                        f"frame change: an Aperture has shape='ellipse'), got "
                        f"{type(surface).__name__}")
    ab = [float(v) for v in half_axes]
    if len(ab) != 2 or not all(0 < v < math.inf for v in ab):
        raise ValueError(f"{type(surface).__name__}: an elliptical {what} needs two half-axes "
                         f"> 0 mm (a along x, b along y), got {half_axes!r}")
    return ab[0], ab[1]


def _set_buffer(surface, name: str, value: torch.Tensor) -> None:
    if name in surface._buffers:
        surface._buffers[name].copy_(value)
    else:
        surface.register_buffer(name, value, persistent=False)


def _keep_decenter(surface) -> None:
    """Give ``surface`` a zero ``clear_decenter`` buffer unless it has one (a set one stays)."""
    if "clear_decenter" not in surface._buffers:
        surface.register_buffer("clear_decenter", torch.zeros(2, dtype=torch.float64),
                                persistent=False)


def _check_built(surface, name: str, what: str) -> None:
    """Undo and refuse when ``surface``'s type builds its opening without the ellipse."""
    if not _has_ellipse(surface.opening, surface._buffers[name]):
        del surface._buffers[name]
        label = what if what.startswith("spider") else f"elliptical {what}"
        raise ValueError(f"{type(surface).__name__}: this surface type's opening has no "
                         f"{label} (it builds its own outline)")


def set_clear_ellipse(surface: Surface, half_axes) -> None:
    """Give ``surface`` an elliptical clear aperture of half-axes ``(a, b)`` (mm; ``a`` along
    the local x axis, ``b`` along y) about its ``clear_decenter`` (zero unless set: Zemax's
    ``ELAP`` with ``OBDC``, CODE V's ``ELX``/``ELY`` with ``ADX``/``ADY``): rays meeting it at
    ``((x - d_x) / a)^2 + ((y - d_y) / b)^2 > 1`` are blocked.  As for
    :func:`set_clear_rect`: the clear radius becomes the circumscribed circle ``max(a, b)`` and
    the semi-diameter ``|d| + max(a, b)``; fixed buffers, not in ``state_dict`` (lens file:
    ``clear_ellipse_mm``); traced on the eager path.  Not beside a clear rectangle."""
    a, b = _half_axes(surface, half_axes, "clear aperture")
    if clear_rect_of(surface) is not None:
        raise ValueError(f"{type(surface).__name__}: an elliptical clear aperture beside a "
                         f"rectangular one is not supported (one surface aperture per surface)")
    r = max(a, b)
    with torch.no_grad():
        _set_buffer(surface, "clear_ellipse", torch.tensor([a, b], dtype=torch.float64))
        _set_buffer(surface, "clear_radius", torch.tensor(r, dtype=torch.float64))
        _keep_decenter(surface)
        dec = [float(v) for v in surface._buffers["clear_decenter"]]
        surface.semi_diameter.fill_(math.hypot(*dec) + r)
    _check_built(surface, "clear_ellipse", "clear aperture")


def clear_ellipse_of(surface) -> tuple[float, float] | None:
    """The half-axes ``(a, b)`` (mm) of ``surface``'s elliptical clear aperture, or ``None``."""
    ell = getattr(surface, "_buffers", {}).get("clear_ellipse")
    return None if ell is None else (float(ell[0]), float(ell[1]))


def set_obscuration_ellipse(surface: Surface, half_axes) -> None:
    """Give ``surface`` an elliptical obscuration of half-axes ``(a, b)`` (mm; ``a`` along the
    local x axis, ``b`` along y) about its vertex (Zemax's ``ELOB``): rays meeting it strictly
    inside ``(x / a)^2 + (y / b)^2 < 1`` are blocked, the rim passes (as a circular
    obscuration's).  A fixed buffer, not in ``state_dict`` (lens file:
    ``obscuration_ellipse_mm``); traced on the eager path."""
    a, b = _half_axes(surface, half_axes, "obscuration")
    if not max(a, b) < float(surface.semi_diameter):
        raise ValueError(f"{type(surface).__name__}: the elliptical obscuration's half-axes "
                         f"({a:g}, {b:g} mm) must be smaller than the semi-diameter "
                         f"({float(surface.semi_diameter):g} mm)")
    with torch.no_grad():
        _set_buffer(surface, "obscuration_ellipse", torch.tensor([a, b], dtype=torch.float64))
    _check_built(surface, "obscuration_ellipse", "obscuration")


def obscuration_ellipse_of(surface) -> tuple[float, float] | None:
    """The half-axes ``(a, b)`` (mm) of ``surface``'s elliptical obscuration, or ``None``."""
    obs = getattr(surface, "_buffers", {}).get("obscuration_ellipse")
    return None if obs is None else (float(obs[0]), float(obs[1]))


def set_obscuration_spider(surface: Surface, spider) -> None:
    """Give ``surface`` a spider obscuration ``spider = (width, n_arms, angle)`` about its vertex
    (:class:`~deeplens.optics.openings.Spider`: ``n_arms`` equally spaced arms of full width
    ``width`` mm, the first at ``angle`` radians from the local +x axis towards +y; Zemax's
    ``SPID``): rays meeting it strictly inside an arm are blocked, the edges pass.  A fixed
    buffer ``obscuration_spider``, not in ``state_dict`` (lens file: ``spider_width_mm``,
    ``spider_arms``, ``spider_angle_deg``); traced on the eager path."""
    if not takes_clear_rect(surface):
        raise TypeError(f"a spider obscuration needs a surface the rays land on (not a stop or a "
                        f"frame change: an Aperture takes spider=...), got "
                        f"{type(surface).__name__}")
    vals = list(spider)
    if len(vals) != 3:
        raise ValueError(f"{type(surface).__name__}: a spider needs (width mm, n_arms, angle "
                         f"rad), got {spider!r}")
    Spider(float(vals[0]), vals[1], float(vals[2]))   # validates
    with torch.no_grad():
        _set_buffer(surface, "obscuration_spider",
                    torch.tensor([float(vals[0]), int(vals[1]), float(vals[2])],
                                 dtype=torch.float64))
    surface._spider_arms = int(vals[1])   # a host int: no read at each clip
    _check_built(surface, "obscuration_spider", "spider obscuration")


def obscuration_spider_of(surface) -> tuple[float, int, float] | None:
    """``(width mm, n_arms, angle rad)`` of ``surface``'s spider obscuration, or ``None``."""
    spi = getattr(surface, "_buffers", {}).get("obscuration_spider")
    return None if spi is None else (float(spi[0]), int(surface._spider_arms), float(spi[2]))


def clear_rect_of(surface) -> tuple[float, float] | None:
    """The half-widths (mm) of ``surface``'s rectangular clear aperture, or ``None``."""
    rect = getattr(surface, "_buffers", {}).get("clear_rect")
    if rect is None or not bool(rect.any()):
        return None
    return float(rect[0]), float(rect[1])
