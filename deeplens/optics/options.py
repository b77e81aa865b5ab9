"""The settings of a trace: :class:`TraceOptions`.

One object carries every knob that changes how rays are traced through a lens, read by the
scheduler (:mod:`.tracer`: eager or compiled runs, checkpointing) and by the intersection
(:mod:`.intersect`: Newton tolerance and iterations, the closed form, clear apertures).
``IntersectOptions`` is its former name (``deeplens.optics.IntersectOptions`` and
``deeplens.optics.intersect.IntersectOptions`` still resolve to it, with a
``DeprecationWarning``).
"""

from __future__ import annotations

from .compile_policy import CompileLedger

__all__ = ["TraceOptions"]


class TraceOptions:
    """How a lens is traced (:mod:`.tracer`).

    Args:
        tol: Newton residual tolerance (mm; ``None``: the dtype's default; never below
            ``4 eps |x|``).
        max_iter: Newton iterations at most.
        mode: ``"implicit"`` (Eq. 7: one differentiable step) or ``"unrolled"`` (for tests).
        clip_aperture: ``False`` ignores clear apertures (ray aiming), not surface domains.
        closed_form: ``False`` runs Newton from the vertex plane also on spheres and conics
            (the reference path).
        checkpoint: keep only each surface's incoming ray state for backward and recompute
            the surface there (about 40 instead of 120 bytes per ray and surface in float32,
            for about 1.5x the backward's time).
        compile: ``"default"`` (the default): eager until compiling would have paid, then
            compiled (:mod:`.compile_policy`: the ski-rental rule, per kernel signature, kept
            in this object's :attr:`ledger`; a one-off call stays eager); ``False`` eager
            always (the off switch; also ``DEEPLENS_COMPILE=0`` for ``"default"``);
            ``"surface"`` runs each aligned sphere, conic, plane, stop, even asphere or XY
            polynomial's intersect + refract as ``torch.compile``d kernels, ``"lens"`` each run
            of aligned spheres, conics, planes and stops as one kernel, ``True`` (``"auto"``)
            picks ``"lens"`` when nothing needs a gradient and ``"surface"`` otherwise
            (measured faster in each case; :mod:`.compiled`; the first call per lens structure
            and dtype compiles, later calls and other ray counts reuse it; a ``record``ed trace,
            ``closed_form=False`` and ``mode="unrolled"`` stay eager).

    Attributes:
        ledger: the :class:`~.compile_policy.CompileLedger` of ``compile="default"`` (each
            options object has its own; :meth:`replace` starts a new one).

    Raises:
        ValueError: an unknown ``compile`` or ``mode``, ``max_iter < 1``, ``tol <= 0``.
    """

    __slots__ = ("checkpoint", "clip_aperture", "closed_form", "compile", "ledger", "max_iter",
                 "mode", "tol")

    def __init__(self, tol: float | None = None, max_iter: int = 30, mode: str = "implicit",
                 clip_aperture: bool = True, closed_form: bool = True, checkpoint: bool = False,
                 compile: bool | str = "default"):
        if compile is True:
            compile = "auto"
        if compile not in (False, None, "default", "auto", "surface", "lens"):
            raise ValueError(f"compile must be 'default', False, True ('auto'), 'surface' or "
                             f"'lens', got {compile!r}")
        self.compile = compile or False
        self.ledger = CompileLedger()
        self.clip_aperture = bool(clip_aperture)
        self.closed_form = bool(closed_form)
        self.checkpoint = bool(checkpoint)
        if mode not in ("implicit", "unrolled"):
            raise ValueError(f"intersection mode must be 'implicit' or 'unrolled', got {mode!r}")
        if max_iter < 1:
            raise ValueError(f"max_iter must be >= 1, got {max_iter}")
        if tol is not None and not tol > 0:
            raise ValueError(f"tol must be > 0 mm, got {tol}")
        self.tol, self.max_iter, self.mode = tol, int(max_iter), mode

    def replace(self, **changes) -> "TraceOptions":
        """A new :class:`TraceOptions` with ``changes`` (keyword arguments of the constructor)
        and every other setting of this one, e.g. ``options.replace(clip_aperture=False)`` for
        the aiming traces of an analysis run at a camera's tolerance and iterations."""
        kw = {k: getattr(self, k) for k in self.__slots__ if k != "ledger"}
        unknown = set(changes) - set(kw)
        if unknown:
            raise TypeError(f"TraceOptions.replace: unknown settings {sorted(unknown)}")
        kw.update(changes)
        return TraceOptions(**kw)

    def __repr__(self):
        return (f"TraceOptions(tol={self.tol}, max_iter={self.max_iter}, mode={self.mode!r}, "
                f"clip_aperture={self.clip_aperture}, closed_form={self.closed_form}, "
                f"checkpoint={self.checkpoint}, compile={self.compile})")
