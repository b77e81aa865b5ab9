"""When compiling the tracer pays: ``TraceOptions(compile="default")``, the default.

``torch.compile`` makes a trace 5-9x faster (:mod:`.compiled`), but compiling one lens structure
costs about half a minute the first time (25-39 s measured on a CPU with an empty inductor cache;
2-8 s once inductor's disk cache holds the kernels).  A one-off analysis call never repays that;
a training run or a design loop of thousands of traces repays it many times.  The default
schedule decides by the classic *ski-rental* rule, which needs no forecast of how many calls
will come: trace eager, and keep, per kernel signature, the seconds compiled kernels would have
saved so far; once that reaches the cost of compiling, compile.  The total time is then at most
twice the better of "always eager" and "compile at once", whatever the workload.

The ledger is kept on the :class:`~.options.TraceOptions` object (a camera's options, reused by
every trace of a training step) and counts modelled seconds, not measured ones, so the step at
which a run switches depends on what it traces, not on the machine's load: a run is as
deterministic as before, and the training module stores the ledger in its checkpoints so that a
resumed run switches at the same step.

Constants (measured, ``benchmarks/bench_compile_kinds.py`` and ``docs/benchmarks.md``): per ray
and fused surface of each kind (sphere or conic, Newton surface, plane or stop), eager costs
:data:`EAGER_S` and compiled :data:`COMPILED_S` CPU seconds (float32, one thread); compiling
costs :data:`COMPILE_COST_S`.  At more threads both traces get faster by about the same factor,
so the model's seconds are CPU seconds, not wall seconds: the step at which a run switches does
not depend on the thread count either.  Calls of
fewer than :data:`MIN_RAYS` rays always run eager (they cost little, and a compiled kernel
specialises on ray counts 0 and 1).

The off switch: ``TraceOptions(compile=False)`` (``render.compile=false`` in a training
config), or the environment variable ``DEEPLENS_COMPILE=0``, which makes ``"default"`` eager
everywhere (forced modes, ``compile=True``/``"surface"``/``"lens"``, still compile).  Where no
compiler is found (inductor's C++ compiler on CPU, Triton on CUDA) ``"default"`` stays eager
and says so once.
"""

from __future__ import annotations

import os
import shutil
import warnings

import torch

__all__ = ["COMPILED_S", "COMPILE_COST_S", "COST_AS", "EAGER_S", "MIN_RAYS", "CompileLedger",
           "compiler_available", "saving_per_ray", "saving_per_ray_surface"]

#: seconds to compile one kernel signature (cold inductor cache, CPU; measured 25-39 s)
COMPILE_COST_S = 30.0
#: eager CPU seconds per ray through one fused surface, by the surface's fused kind
#: (:func:`~.tracer.fused_kind`) and gradients (without / with): one thread, 1e5 rays through
#: eight surfaces of one kind, the shape parameters trainable
#: (``benchmarks/bench_compile_kinds.py``, docs/benchmarks.md).  A Newton surface (even
#: asphere, XY polynomial) iterates its intersection: eager it costs 3-5 spheres, and compiling
#: saves 2-4 times what it saves on a sphere.
EAGER_S = {
    "quadric": {False: 8.2e-8, True: 1.95e-7},
    "newton": {False: 2.8e-7, True: 5.0e-7},
    "plane": {False: 9.3e-8, True: 1.49e-7},
}
#: the same, compiled (for ``"newton"`` the even asphere's, whose saving is the smaller: an XY
#: polynomial saves 3.2e-7 / 4.8e-7)
COMPILED_S = {
    "quadric": {False: 3.05e-8, True: 1.12e-7},
    "newton": {False: 9.4e-8, True: 1.63e-7},
    "plane": {False: 1.6e-8, True: 4.9e-8},
}
#: fused kinds costed as another: a stop is a plane's intersection and clip, no refraction
COST_AS = {"stop": "plane", "stop_rect": "plane"}
#: calls with fewer rays always run eager
MIN_RAYS = 4096


def saving_per_ray_surface(kind: str, grad: bool) -> float:
    """Modelled seconds compiling saves per ray through one fused surface of ``kind`` (a
    :func:`~.tracer.fused_kind` value); never negative."""
    k = COST_AS.get(kind, kind)
    return max(EAGER_S[k][grad] - COMPILED_S[k][grad], 0.0)


def saving_per_ray(kinds, grad: bool) -> float:
    """Modelled seconds compiling saves per ray through a lens whose surfaces have the fused
    kinds ``kinds`` (``None``: runs eager either way)."""
    return sum(saving_per_ray_surface(k, grad) for k in kinds if k is not None)


def compiler_available(device: torch.device) -> tuple[bool, str]:
    """Whether ``torch.compile`` can build kernels for ``device`` here, and if not, why."""
    if device.type == "cuda":
        try:
            from torch.utils._triton import has_triton
        except ImportError:  # pragma: no cover - torch without the helper
            return False, "torch has no Triton check"
        return (True, "") if has_triton() else (False, "Triton is not installed")
    if device.type != "cpu":
        return False, f"no compiled kernels for device {device.type!r}"
    try:
        from torch._inductor.cpp_builder import get_cpp_compiler
        cxx = get_cpp_compiler()
    except Exception as e:  # noqa: BLE001 - any failure means: no compiler
        return False, f"inductor finds no C++ compiler ({e})"
    if shutil.which(str(cxx).split()[0]) is None:
        return False, f"the C++ compiler {cxx!r} is not on PATH"
    return True, ""


class CompileLedger:
    """The ski-rental account of one :class:`~.options.TraceOptions` (module docstring).

    ``saved[key]``: the modelled seconds that compiled kernels would have saved so far on the
    calls of one kernel signature ``key`` (lens structure, dtype, device, gradients or not,
    direction); at :data:`COMPILE_COST_S` that signature compiles.
    """

    __slots__ = ("_compiler", "saved")

    def __init__(self):
        self.saved: dict[str, float] = {}
        self._compiler: dict[str, bool] = {}

    def charge(self, key: str, n_rays: int, kinds, grad: bool,
               device: torch.device) -> bool:
        """Whether this call of ``n_rays`` rays through surfaces of the fused kinds ``kinds``
        (:func:`~.tracer.fused_kind` per surface, ``None`` for an eager one) should run
        compiled; an eager call adds what compiling would have saved on it
        (:func:`saving_per_ray`)."""
        if n_rays < MIN_RAYS or all(k is None for k in kinds):
            return False
        if os.environ.get("DEEPLENS_COMPILE", "").strip() == "0":
            return False
        if self.paid(key):
            return self.can_compile(device)
        self.saved[key] = self.saved.get(key, 0.0) + n_rays * saving_per_ray(kinds, grad)
        return False

    def paid(self, key: str) -> bool:
        """Whether signature ``key`` has saved the cost of compiling (it now runs compiled)."""
        return self.saved.get(key, 0.0) >= COMPILE_COST_S

    def can_compile(self, device: torch.device) -> bool:
        """Whether kernels can be compiled for ``device`` here (checked once per device type;
        if not, one warning says why)."""
        if device.type not in self._compiler:
            ok, why = compiler_available(device)
            self._compiler[device.type] = ok
            if not ok:
                warnings.warn(f"TraceOptions(compile='default'): the compiled tracer would pay "
                              f"here, but {why}; tracing eager", RuntimeWarning, stacklevel=4)
        return self._compiler[device.type]

    def state_dict(self) -> dict:
        """The account (plain floats), for a checkpoint."""
        return {"saved": dict(self.saved)}

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict`'s account (a resumed run then switches at the same
        call)."""
        self.saved = {str(k): float(v) for k, v in dict(state.get("saved", {})).items()}

    def __repr__(self):
        return f"CompileLedger({len(self.saved)} signatures)"
