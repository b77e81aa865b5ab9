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

Constants (measured, ``benchmarks/bench_compile_policy.py`` and ``docs/benchmarks.md``):
per ray and fused surface, eager costs :data:`EAGER_S` and compiled :data:`COMPILED_S` seconds
(double Gauss, float32, CPU, two threads); compiling costs :data:`COMPILE_COST_S`.  Calls of
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

__all__ = ["COMPILED_S", "COMPILE_COST_S", "EAGER_S", "MIN_RAYS", "CompileLedger",
           "compiler_available"]

#: seconds to compile one kernel signature (cold inductor cache, CPU; measured 25-39 s)
COMPILE_COST_S = 30.0
#: eager seconds per ray and fused surface, without / with gradients (double Gauss, float32,
#: two threads: 0.475 s forward and 0.903 s trace + backward for 1e6 rays x 11 surfaces)
EAGER_S = {False: 4.3e-8, True: 8.2e-8}
#: the same, compiled (0.053 s and 0.194 s)
COMPILED_S = {False: 4.8e-9, True: 1.8e-8}
#: calls with fewer rays always run eager
MIN_RAYS = 4096


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

    def charge(self, key: str, n_rays: int, n_fused: int, grad: bool,
               device: torch.device) -> bool:
        """Whether this call of ``n_rays`` rays through ``n_fused`` compilable surfaces
        should run compiled; an eager call adds what compiling would have saved on it."""
        if n_rays < MIN_RAYS or n_fused == 0:
            return False
        if os.environ.get("DEEPLENS_COMPILE", "").strip() == "0":
            return False
        if self.paid(key):
            return self.can_compile(device)
        self.saved[key] = (self.saved.get(key, 0.0)
                           + n_rays * n_fused * (EAGER_S[grad] - COMPILED_S[grad]))
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
