"""The camera: a lens, the sensor behind it and the settings every trace of it runs with.

A :class:`Camera` is what renderers (:mod:`deeplens.render`), the Wiener front end
(:mod:`deeplens.training.wiener`), the PSF functions and the training module take, so that one
:class:`~.options.TraceOptions` reaches every trace of a training step: each of them reads
``camera.options`` when it traces (never a copy taken at construction), so replacing
``camera.options`` changes all of them at once.

Ownership (the one rule): **the camera owns the lens.**  Which lens parameters train is chosen
in one place, :meth:`Camera.set_trainable` (``lens.trainable`` of a training config;
:meth:`Camera.freeze_lens` freezes all); fixing them for a while (``optics_warmup_steps``) is
:meth:`Camera.lens_fixed`.  Objects that hold a camera (renderers, the Wiener filter, the
end-to-end module) read the lens and trace it; they never change which parameters require
gradients.  The lens's values change only through the optimiser of the module that holds the
camera (its parameter groups come from :meth:`Camera.trainable_parameters`) or inside a
context that restores them (a tolerance draw).  A camera's lens and sensor are fixed at
construction (build another camera for another lens); its options may be replaced any time.

The sensor is held, not interpreted: the optics layer does not import the pixel grid and
noise model (:class:`deeplens.render.sensor.Sensor`) above it, so the camera lives here, where
the renderers, the analysis code and the design engine can all import it.
"""

from __future__ import annotations

import contextlib

from torch import nn

from .lens import Lens
from .options import TraceOptions
from .parameters import select_names
from .rays import Rays

__all__ = ["Camera", "HoldsCamera", "as_camera", "set_trainable", "unpack"]


def set_trainable(lens, patterns, what: str = "lens.trainable") -> list[str]:
    """Make exactly the parameters of ``lens`` matching ``patterns`` (names or ``fnmatch``
    globs, :func:`~.parameters.select_names`) require gradients and freeze the others; returns
    the chosen names in pattern order.

    Raises:
        ValueError: a pattern matches no parameter (the message names ``what`` and lists the
            available names).
    """
    names = [n for n, _ in lens.named_parameters()]
    chosen = select_names(names, patterns or [], f"{what}: ")
    params = dict(lens.named_parameters())
    for n in names:
        params[n].requires_grad_(n in chosen)
    return chosen


class HoldsCamera:
    """Mixin of the objects that trace through a camera they hold but do not own (renderers,
    the Wiener filter): the camera sits in ``self._held = (camera,)``, a tuple, so that
    ``nn.Module`` does not register it (the module that built it owns it); ``options`` reads and
    sets the camera's, so nothing keeps a copy."""

    @property
    def camera(self) -> "Camera":
        """The :class:`Camera` traced through."""
        return self._held[0]

    @property
    def options(self) -> TraceOptions:
        """The camera's trace options (read at every trace; setting them sets the camera's)."""
        return self.camera.options

    @options.setter
    def options(self, value) -> None:
        self.camera.options = value


class Camera(nn.Module):
    """A lens, its sensor and its trace settings (module docstring: who owns the lens).

    Args:
        lens: the :class:`~.lens.Lens` (registered: ``camera.parameters()`` are the lens's
            and the sensor's).
        sensor: the sensor (e.g. :class:`deeplens.render.sensor.Sensor`: pixel grid,
            channels, noise), or ``None`` for analysis that needs none.
        options: the :class:`~.options.TraceOptions` of every trace through this camera
            (``None``: the defaults).

    Raises:
        TypeError: ``lens`` is not a :class:`~.lens.Lens`, ``options`` not a
            :class:`~.options.TraceOptions`.
        ValueError: a ``sensor`` for a lens whose image plane is virtual
            (:meth:`Lens.require_real_image <.lens.Lens.require_real_image>`).
    """

    def __init__(self, lens: Lens, sensor: nn.Module | None = None,
                 options: TraceOptions | None = None):
        super().__init__()
        if not isinstance(lens, Lens):
            raise TypeError(f"Camera: lens must be a Lens, got {type(lens).__name__}")
        if sensor is not None:   # a virtual image plane cannot be recorded
            lens.require_real_image("Camera(lens, sensor)")
        self.lens = lens
        self.sensor = sensor
        self.options = options

    # ------------------------------------------------------------------ settings
    @property
    def options(self) -> TraceOptions:
        """The :class:`~.options.TraceOptions` every trace through the camera runs with;
        assigning ``None`` restores the defaults."""
        return self._options

    @options.setter
    def options(self, value: TraceOptions | None) -> None:
        if value is None:
            value = TraceOptions()
        if not isinstance(value, TraceOptions):
            raise TypeError(f"Camera.options: expected a TraceOptions, got "
                            f"{type(value).__name__}")
        self._options = value

    @property
    def dtype(self):
        return self.lens.dtype

    @property
    def device(self):
        return self.lens.device

    # ------------------------------------------------------------------ tracing
    def trace(self, rays: Rays, *, reverse: bool = False, record: bool = False,
              propagate_to=None):
        """:meth:`Lens.trace <.lens.Lens.trace>` with the camera's options."""
        return self.lens.trace(rays, reverse=reverse, options=self.options, record=record,
                               propagate_to=propagate_to)

    def trace_to_sensor(self, rays: Rays, *, z_image=None) -> Rays:
        """:meth:`Lens.trace_to_sensor <.lens.Lens.trace_to_sensor>` with the camera's
        options."""
        return self.lens.trace_to_sensor(rays, z_image=z_image, options=self.options)

    # ------------------------------------------------------------------ the lens's parameters
    def set_trainable(self, patterns) -> list[str]:
        """Exactly the lens parameters matching ``patterns`` train (:func:`set_trainable`);
        returns their names."""
        return set_trainable(self.lens, patterns)

    def freeze_lens(self) -> None:
        """No lens parameter trains (``set_trainable([])``)."""
        for p in self.lens.parameters():
            p.requires_grad_(False)

    def trainable_parameters(self) -> list[tuple[str, nn.Parameter]]:
        """``(name, parameter)`` of the lens parameters that train, in
        ``lens.named_parameters()`` order."""
        return [(n, p) for n, p in self.lens.named_parameters() if p.requires_grad]

    @contextlib.contextmanager
    def lens_fixed(self, fixed: bool = True):
        """While ``fixed``, no lens parameter requires a gradient (traces run without autograd
        through the lens; the values are unchanged); the trainable set is restored on exit."""
        params = [p for p in self.lens.parameters() if p.requires_grad] if fixed else []
        for p in params:
            p.requires_grad_(False)
        try:
            yield
        finally:
            for p in params:
                p.requires_grad_(True)

    def extra_repr(self) -> str:
        return f"options={self.options!r}"


def as_camera(lens_or_camera, sensor=None, options: TraceOptions | None = None,
              where: str = "") -> Camera:
    """The :class:`Camera` of a call that takes either a camera or (the older form) a lens
    with ``sensor`` and ``options``.  A camera is returned as it is; giving it ``options`` or
    another ``sensor`` as well is refused (the camera's settings are the one setting).

    Raises:
        ValueError: a camera together with ``options`` or a different ``sensor``.
        TypeError: neither a camera nor a lens.
    """
    if isinstance(lens_or_camera, Camera):
        cam = lens_or_camera
        who = f"{where}: " if where else ""
        if options is not None and options is not cam.options:
            raise ValueError(f"{who}options given beside a Camera; set camera.options instead "
                             f"(one setting for every trace of the camera)")
        if sensor is not None and sensor is not cam.sensor:
            raise ValueError(f"{who}a sensor given beside a Camera with another sensor")
        return cam
    if sensor is not None and isinstance(lens_or_camera, Lens):   # name the caller
        lens_or_camera.require_real_image(where or "Camera(lens, sensor)")
    return Camera(lens_or_camera, sensor, options)


def unpack(lens_or_camera, sensor=None, options: TraceOptions | None = None, where: str = ""):
    """``(lens, sensor, options)`` for a function that takes a lens (with ``sensor`` and
    ``options``) or a :class:`Camera` in its place (then ``sensor`` may be ``None`` and the
    options are the camera's).  A lens passes through with ``sensor`` and ``options`` as
    given (``None`` stays ``None``: the defaults), so the older calls trace as before.

    Raises:
        ValueError: a camera together with ``options`` or a different ``sensor``
            (:func:`as_camera`); a lens with a virtual image plane given with a ``sensor``
            (:meth:`Lens.require_real_image <.lens.Lens.require_real_image>`).
    """
    if isinstance(lens_or_camera, Camera):
        cam = as_camera(lens_or_camera, sensor, options, where)
        return cam.lens, cam.sensor, cam.options
    if sensor is not None and isinstance(lens_or_camera, Lens):   # a sensor to record on
        lens_or_camera.require_real_image(where or "a lens with a sensor")
    return lens_or_camera, sensor, options
