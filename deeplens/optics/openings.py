"""Openings: where a surface lets rays through, as objects that compose.

An opening is a closed region of the surface's local ``x-y`` plane (mm): a ray that meets the
surface at ``(x, y)`` passes if ``opening.contains(x, y)``.  Every surface has one
(``surface.opening``, used by :meth:`~.surfaces.Surface.in_aperture`, by the eager tracer and by
the compiled one, whose fused kernels clip by a centred circle or rectangle only:
:attr:`Opening.kernel_clip`).  The primitives, each with an optional ``decenter = (d_x, d_y)``
(mm, the centre of the opening in the plane):

* :class:`Circle` ``(radius)``: ``(x - d_x)^2 + (y - d_y)^2 <= r^2``;
* :class:`Rectangle` ``(half_widths)``: ``|x - d_x| <= w_x`` and ``|y - d_y| <= w_y``;
* :class:`Ellipse` ``(half_axes)``: ``((x - d_x) / a)^2 + ((y - d_y) / b)^2 <= 1``, ``a`` along
  the local x axis and ``b`` along y (Zemax's ``ELAP``/``ELOB``, CODE V's ``ELX``/``ELY``);
* :class:`Spider` ``(width, n_arms, angle)``: ``n_arms`` straight arms of full width ``width``
  from the centre outwards, equally spaced, the first at ``angle`` (radians from the local +x
  axis towards +y): a telescope's secondary supports (Zemax's ``SPID``), used as an obscuration
  (``outer - Spider(...)``);
* :class:`Everywhere`: no limit (a coordinate break).

and their compositions: ``a & b`` (:class:`Intersection`: inside both) and ``a - b``
(:class:`Difference`: inside ``a`` and not strictly inside ``b``), so ``Circle(r) -
Circle(r_o)`` is an annulus (:func:`annulus`: a central obscuration).  The values are tensors
(0-d radius, ``(2,)`` half-widths and decenter, float64 buffers of the surface that the opening
is built from: the surface's ``state_dict`` and lens file keep their fields) or numbers; they are
converted to the rays' dtype where tested, with the same expressions the kernels use
(:func:`in_circle`, :func:`in_rect`), so a refactor of the clipping changes no bit.

Example::

    >>> import torch
    >>> ring = Circle(torch.tensor(2.0)) - Circle(torch.tensor(0.5))
    >>> ring.contains(torch.tensor([0.0, 1.0, 3.0]), torch.tensor([0.0, 0.0, 0.0]))
    tensor([False,  True, False])
"""

from __future__ import annotations

import math

import torch

__all__ = ["Opening", "Circle", "Rectangle", "Ellipse", "Spider", "Everywhere", "Intersection",
           "Difference", "annulus", "in_circle", "in_rect", "in_ellipse"]


def in_circle(X, Y, r):
    """``X^2 + Y^2 <= r^2``: inside a circle of radius ``r`` (mm) about the origin; the eager
    clip and the compiled kernels' aperture check."""
    return X * X + Y * Y <= r * r


def in_rect(X, Y, half_widths):
    """``|X| <= w_x`` and ``|Y| <= w_y``: inside a rectangle about the origin, ``half_widths``
    ``(2,)`` mm; the eager clip and the compiled kernels' check."""
    return (X.abs() <= half_widths[0]) & (Y.abs() <= half_widths[1])


def in_ellipse(X, Y, half_axes):
    """``(X / a)^2 + (Y / b)^2 <= 1``: inside an ellipse about the origin of half-axes
    ``half_axes = (a, b)`` (mm; ``a`` along x, ``b`` along y).  Shapes: ``X``, ``Y`` ``(*B,)``,
    ``half_axes`` ``(2,)``; returns ``(*B,)`` bool.  Eager only (no fused kernel clips by it)."""
    u, v = X / half_axes[0], Y / half_axes[1]
    return u * u + v * v <= 1.0


def _tensor(v, shape=()):
    t = torch.as_tensor(v, dtype=torch.float64) if not torch.is_tensor(v) else v
    if tuple(t.shape) != shape:
        raise ValueError(f"expected a value of shape {shape} (mm), got {tuple(t.shape)}")
    return t


class Opening:
    """Base class (module docstring).  Subclasses give :meth:`contains` and :meth:`outside`
    (the closed complement of the interior: ``a - b`` keeps ``b``'s boundary) and
    :meth:`bounds`."""

    #: ``"circle"``, ``"rect"``, ``"ellipse"``, ``"everywhere"``, ``"intersection"`` or
    #: ``"difference"``
    kind = "opening"

    def contains(self, x, y):
        """``(*B,)`` bool: ``(x, y)`` (mm, local frame, ``(*B,)`` each) lies in the opening."""
        raise NotImplementedError

    def outside(self, x, y):
        """``(*B,)`` bool: ``(x, y)`` lies outside the opening's interior (on its boundary or
        beyond)."""
        raise NotImplementedError

    def bounds(self) -> tuple[tuple[float, float], float]:
        """``((c_x, c_y), r)``: a circle (mm) that holds the opening (for sampling a surface's
        used part, :meth:`Lens.check <deeplens.optics.lens.Lens.check>`)."""
        raise NotImplementedError

    @property
    def kernel_clip(self):
        """``("circle", r)`` or ``("rect", half_widths)`` when the opening is one centred
        circle or rectangle (the fused kernels' clip), else ``None`` (the surface runs eager)."""
        return None

    @property
    def outer(self) -> "Opening":
        """The opening before anything is taken out of it (``a`` of ``a - b``)."""
        return self

    def __and__(self, other: "Opening") -> "Opening":
        return Intersection(self, other)

    def __sub__(self, other: "Opening") -> "Opening":
        return Difference(self, other)


class _Centred(Opening):
    """A primitive with a decenter: ``(x, y)`` is shifted before its test.  ``check=False``
    (the surfaces' own openings, built at every clip): the values are taken as given, without
    validation (no host synchronisation), a zero decenter included."""

    def __init__(self, decenter=None, check: bool = True):
        if decenter is not None and check:
            decenter = _tensor(decenter, (2,))
            if not bool(torch.isfinite(decenter).all()):
                raise ValueError(f"{type(self).__name__}: decenter must be two finite numbers "
                                 f"of mm, got {decenter.tolist()}")
            if not bool(decenter.any()):
                decenter = None
        self.decenter = decenter

    def _local(self, x, y):
        if self.decenter is None:
            return x, y
        return x - self.decenter[0].to(x), y - self.decenter[1].to(x)

    def _centre(self) -> tuple[float, float]:
        return (0.0, 0.0) if self.decenter is None else tuple(float(v) for v in self.decenter)


class Circle(_Centred):
    """A circle of radius ``radius`` (mm, ``> 0``; ``inf``: no limit) about ``decenter``."""

    kind = "circle"

    def __init__(self, radius, decenter=None, check: bool = True):
        super().__init__(decenter, check)
        self.radius = _tensor(radius) if check else radius
        if check and not float(self.radius) > 0:
            raise ValueError(f"Circle: the radius must be > 0 mm, got {float(self.radius)!r}")

    def contains(self, x, y):
        u, v = self._local(x, y)
        return in_circle(u, v, self.radius.to(x))

    def outside(self, x, y):
        u, v = self._local(x, y)
        r = self.radius.to(x)
        return u * u + v * v >= r * r

    def bounds(self):
        return self._centre(), float(self.radius)

    @property
    def kernel_clip(self):
        return ("circle", self.radius) if self.decenter is None else None

    def __repr__(self) -> str:
        return f"Circle({float(self.radius):g}" + (
            f", decenter={list(self._centre())})" if self.decenter is not None else ")")


class Rectangle(_Centred):
    """A rectangle of half-widths ``(w_x, w_y)`` (mm, ``> 0``) about ``decenter``."""

    kind = "rect"

    def __init__(self, half_widths, decenter=None, check: bool = True):
        super().__init__(decenter, check)
        self.half_widths = _tensor(half_widths, (2,)) if check else half_widths
        if check and not bool((self.half_widths > 0).all()):
            raise ValueError(f"Rectangle: half-widths must be > 0 mm, got "
                             f"{self.half_widths.tolist()}")

    def contains(self, x, y):
        u, v = self._local(x, y)
        return in_rect(u, v, self.half_widths.to(x))

    def outside(self, x, y):
        u, v = self._local(x, y)
        hw = self.half_widths.to(x)
        return (u.abs() >= hw[0]) | (v.abs() >= hw[1])

    def bounds(self):
        return self._centre(), math.hypot(*(float(v) for v in self.half_widths))

    @property
    def kernel_clip(self):
        return ("rect", self.half_widths) if self.decenter is None else None

    def __repr__(self) -> str:
        return f"Rectangle({[float(v) for v in self.half_widths]}" + (
            f", decenter={list(self._centre())})" if self.decenter is not None else ")")


class Ellipse(_Centred):
    """An ellipse of half-axes ``(a, b)`` (mm, ``> 0``; ``a`` along the local x axis, ``b``
    along y) about ``decenter``: ``((x - d_x) / a)^2 + ((y - d_y) / b)^2 <= 1``
    (:func:`in_ellipse`).  With ``a = b`` it is the circle of that radius.  Never a fused
    kernel's clip (:attr:`kernel_clip` is ``None``): a surface with one runs eager."""

    kind = "ellipse"

    def __init__(self, half_axes, decenter=None, check: bool = True):
        super().__init__(decenter, check)
        self.half_axes = _tensor(half_axes, (2,)) if check else half_axes
        if check and not bool(((self.half_axes > 0) & torch.isfinite(self.half_axes)).all()):
            raise ValueError(f"Ellipse: half-axes must be finite and > 0 mm, got "
                             f"{self.half_axes.tolist()}")

    def contains(self, x, y):
        u, v = self._local(x, y)
        return in_ellipse(u, v, self.half_axes.to(x))

    def outside(self, x, y):
        u, v = self._local(x, y)
        ab = self.half_axes.to(x)
        p, q = u / ab[0], v / ab[1]
        return p * p + q * q >= 1.0

    def bounds(self):
        return self._centre(), max(float(v) for v in self.half_axes)

    def __repr__(self) -> str:
        return f"Ellipse({[float(v) for v in self.half_axes]}" + (
            f", decenter={list(self._centre())})" if self.decenter is not None else ")")


class Spider(_Centred):
    """``n_arms`` arms of full width ``width`` (mm, ``> 0``), each a half-strip from the centre
    (``decenter``) outwards, equally spaced: arm ``j`` runs along ``u_j = (cos t_j, sin t_j)``,
    ``t_j = angle + 2 pi j / n_arms`` (``angle`` in radians, from the local +x axis towards +y).
    A point ``q`` (relative to the centre) lies inside arm ``j`` when ``q . u_j > 0`` (on the
    arm's side of the centre) and ``|q x u_j| < width / 2`` (strictly within half the width of
    its centre line); the region is the union of the arms, unbounded outwards (an obscuration:
    ``Circle(r) - Spider(...)`` blocks the arms within the circle, their edges pass).  Zemax's
    ``SPID width n`` with the first arm along +x; a frame turned about z turns ``angle``."""

    kind = "spider"

    def __init__(self, width, n_arms: int, angle=0.0, decenter=None, check: bool = True):
        super().__init__(decenter, check)
        if check:
            if isinstance(n_arms, bool) or int(n_arms) != n_arms or not int(n_arms) >= 1:
                raise ValueError(f"Spider: the number of arms must be an integer >= 1, got "
                                 f"{n_arms!r}")
            w = float(width)
            if not 0 < w < math.inf:
                raise ValueError(f"Spider: the arm width must be finite and > 0 mm, got {w!r}")
            if not math.isfinite(float(angle)):
                raise ValueError(f"Spider: the first arm's angle must be finite, got {angle!r}")
        self.width = _tensor(width) if check else width
        self.n_arms = int(n_arms)
        self.angle = _tensor(angle) if check else angle

    def _arms(self, x, y):
        """``(along, across)``, each ``(n_arms, *B)``: the coordinates of ``(x, y)`` along
        and across each arm's centre line."""
        u, v = self._local(x, y)
        j = torch.arange(self.n_arms, dtype=torch.float64, device=x.device)
        t = (self.angle.to(torch.float64).to(x.device) + 2.0 * math.pi * j / self.n_arms)
        c, s = torch.cos(t).to(x.dtype), torch.sin(t).to(x.dtype)
        shape = (self.n_arms,) + (1,) * u.dim()
        c, s = c.reshape(shape), s.reshape(shape)
        return u * c + v * s, v * c - u * s

    def contains(self, x, y):
        along, across = self._arms(x, y)
        half = 0.5 * self.width.to(x)
        return ((along > 0) & (across.abs() < half)).any(dim=0)

    def outside(self, x, y):
        return ~self.contains(x, y)

    def bounds(self):
        return self._centre(), math.inf

    def __repr__(self) -> str:
        return (f"Spider({float(self.width):g}, {self.n_arms}, angle={float(self.angle):g}"
                + (f", decenter={list(self._centre())})" if self.decenter is not None else ")"))


class Everywhere(Opening):
    """No limit: every point passes (a coordinate break, which is not a physical surface)."""

    kind = "everywhere"

    def contains(self, x, y):
        return torch.ones_like(x, dtype=torch.bool)

    def outside(self, x, y):
        return torch.zeros_like(x, dtype=torch.bool)

    def bounds(self):
        return (0.0, 0.0), math.inf

    def __repr__(self) -> str:
        return "Everywhere()"


class Intersection(Opening):
    """Inside every one of ``parts`` (``a & b & ...``)."""

    kind = "intersection"

    def __init__(self, *parts: Opening):
        flat = []
        for p in parts:
            flat += list(p.parts) if isinstance(p, Intersection) else [p]
        self.parts = tuple(flat)

    def contains(self, x, y):
        inside = self.parts[0].contains(x, y)
        for p in self.parts[1:]:
            inside = inside & p.contains(x, y)
        return inside

    def outside(self, x, y):
        out = self.parts[0].outside(x, y)
        for p in self.parts[1:]:
            out = out | p.outside(x, y)
        return out

    def bounds(self):
        """The smallest of the parts' circles (the first of equal ones)."""
        return min((p.bounds() for p in self.parts), key=lambda b: b[1])

    def __repr__(self) -> str:
        return " & ".join(map(repr, self.parts))


class Difference(Opening):
    """Inside ``a`` and not strictly inside ``b`` (``a - b``; ``b``'s boundary passes)."""

    kind = "difference"

    def __init__(self, a: Opening, b: Opening):
        self.a, self.b = a, b

    def contains(self, x, y):
        return self.a.contains(x, y) & self.b.outside(x, y)

    def outside(self, x, y):
        return self.a.outside(x, y) | self.b.contains(x, y)

    def bounds(self):
        return self.a.bounds()

    @property
    def outer(self) -> Opening:
        return self.a.outer

    def __repr__(self) -> str:
        return f"({self.a!r}) - ({self.b!r})"


def annulus(outer, inner, decenter=None, check: bool = True) -> Opening:
    """``Circle(outer) - Circle(inner)`` about the same ``decenter``: a central obscuration of
    radius ``inner`` (mm) in a circular opening of radius ``outer``."""
    return Circle(outer, decenter, check) - Circle(inner, decenter, check)
