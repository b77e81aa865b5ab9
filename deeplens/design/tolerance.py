"""Monte Carlo tolerancing: the merit distribution of randomly perturbed lenses.

Each of ``N`` trials draws every tolerance parameter independently and uniformly in
``θ_j + [-t_j, t_j]`` (standard deviation ``σ_j = t_j / sqrt 3``) and evaluates the per-field
merit ``ε_f`` (:func:`~.sensitivity.field_merits`) on the pupil regions of the nominal lens.
The percentiles of ``ε_f`` over the trials are compared with the RSS estimate of
:func:`~.sensitivity.rss_estimate` (same ``σ_j``).

Tolerance files (JSON) map parameter names or globs to half-widths in the parameter's units
(mm, rad, 1/mm), or to ``"P%"`` for a relative half-width::

    {"misalignments.*.dx": 0.02, "misalignments.*.dy": 0.02,
     "misalignments.*.tilt_*": 0.0005, "distances.*": 0.02, "surfaces.*.c": "0.5%"}

Only parameters of :func:`~.sensitivity.tolerance_parameters` are perturbed (``distances.0``,
the stop and frozen air elements are not).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import torch

from ..optics.parameters import glob_names
from .sensitivity import _split, _unscaled, field_merits, tolerance_parameters
from .variables import on_camera

__all__ = ["DEFAULT_TOLERANCES", "load_tolerances", "resolve_tolerances", "monte_carlo",
           "monte_carlo_figure"]

#: decenter 20 µm, tilt 0.5 mrad (1.7 arcmin), spacing 20 µm, curvature 0.5 %
DEFAULT_TOLERANCES = {"misalignments.*.dx": 0.02, "misalignments.*.dy": 0.02,
                      "misalignments.*.tilt_x": 5e-4, "misalignments.*.tilt_y": 5e-4,
                      "distances.*": 0.02, "surfaces.*.c": "0.5%"}


def load_tolerances(path) -> dict:
    """Read a tolerance file (module docstring); errors name the file and the key."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except OSError as e:
        raise ValueError(f"--tolerances: cannot read {path}: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"--tolerances: {path} is not valid JSON (line {e.lineno}: "
                         f"{e.msg})") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"--tolerances: {path} must hold a JSON object of name/glob -> "
                         f"half-width")
    for k, v in data.items():
        _halfwidth(v, 1.0, f"{path}: {k!r}")
    return data


def _halfwidth(v, nominal, where):
    if isinstance(v, str) and v.strip().endswith("%"):
        try:
            frac = float(v.strip()[:-1]) / 100.0
        except ValueError:
            raise ValueError(f"{where}: expected a number or 'P%', got {v!r}") from None
        t = abs(frac * nominal)
    elif isinstance(v, (int, float)) and not isinstance(v, bool):
        t = float(v)
    else:
        raise ValueError(f"{where}: expected a number or 'P%', got {v!r}")
    if not (math.isfinite(t) and t >= 0):
        raise ValueError(f"{where}: the half-width must be finite and >= 0, got {v!r}")
    return t


def resolve_tolerances(lens, spec: dict | None = None) -> tuple[list[str], torch.Tensor]:
    """``(names, half_widths (P,))``: tolerance parameters of ``lens`` matched by ``spec``
    (the last matching key wins); parameters matched by none are left out.

    Raises:
        ValueError: a key that matches no tolerance parameter (the message lists them).
    """
    spec = DEFAULT_TOLERANCES if spec is None else spec
    cands = tolerance_parameters(lens)
    params = dict(lens.named_parameters())
    chosen = {}
    for key, v in spec.items():
        for n in glob_names(cands, key, "tolerance ", "tolerance parameter"):
            chosen[n] = _halfwidth(v, float(params[n]), f"tolerance {key!r}")
    names = [n for n in cands if n in chosen and chosen[n] > 0]
    return names, torch.tensor([chosen[n] for n in names], dtype=torch.float64)


def monte_carlo(lens, merit, names, half_widths, n: int = 100, seed: int = 0,
                model=None) -> dict:
    """Evaluate ``n`` perturbed lenses (module docstring); ``merit`` is a
    :class:`~.merit.SpotMerit` prepared on the nominal lens (``strict_rays`` is ignored: lost
    rays are dropped as vignetted).  With a tolerance group ``model``
    (:class:`~deeplens.optics.tolerance_model.ToleranceModel`) trial ``k`` is instead the lens it draws with
    seed ``seed + k`` (``names``/``half_widths`` unused): the lenses training and evaluation
    under that group draw.  ``lens``: a Lens or a :class:`~deeplens.optics.camera.Camera` (its
    options reach every trace of the merit and of the draws' centring).

    Returns:
        ``{"n", "seed", "nominal_um" (F,), "samples_um" (n, F), "percentiles_um":
        {"50", "90", "98"} -> (F,), "mean_um", "rms_um" (F,)}`` (lists).
    """
    if n < 1:
        raise ValueError(f"--monte-carlo must be >= 1, got {n}")
    t = torch.as_tensor(half_widths, dtype=torch.float64)
    cam, lens = _split(lens, "monte_carlo")
    if model is not None:
        from ..optics.tolerance_model import call_drawn

        def trial(k):
            return call_drawn(on_camera(cam, lens), model.draw(lens, int(seed) + k),
                              lambda L: field_merits(merit, L))
        nominal_of = (lambda: field_merits(merit, on_camera(cam, lens)))  # noqa: E731
    else:
        v = _unscaled(lens, names)
        x0 = v.x0()
        g = torch.Generator().manual_seed(int(seed))

        def trial(k):
            u = 2.0 * torch.rand(len(names), generator=g, dtype=torch.float64) - 1.0
            return v.call(lambda L: field_merits(merit, on_camera(cam, L)), x0 + u * t)
        def nominal_of():
            return v.call(lambda L: field_merits(merit, on_camera(cam, L)), x0)
    strict = merit.strict_rays
    merit.strict_rays = False
    samples = []
    try:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad")
            nominal = nominal_of()
            samples = [trial(k) for k in range(n)]
    finally:
        merit.strict_rays = strict
    s = torch.stack(samples) * 1e3
    q = {str(p): torch.quantile(s, p / 100.0, dim=0).tolist() for p in (50, 90, 98)}
    return {"n": n, "seed": int(seed), "fields_deg": list(merit.fields),
            "nominal_um": (nominal * 1e3).tolist(), "samples_um": s.tolist(),
            "percentiles_um": q, "mean_um": s.mean(0).tolist(),
            "rms_um": torch.sqrt((s * s).mean(0)).tolist()}


def monte_carlo_figure(mc: dict, rss_um=None):
    """Histograms of the per-field merit over the trials, with the nominal value, the 90th
    percentile and (optionally) the RSS estimate marked; returns a matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    s = torch.tensor(mc["samples_um"])
    F = s.shape[1]
    fig, axes = plt.subplots(1, F, figsize=(4 * F, 3.2), dpi=90, squeeze=False)
    for f in range(F):
        ax = axes[0, f]
        ax.hist(s[:, f].numpy(), bins=max(10, min(40, s.shape[0] // 5)), color="0.6")
        ax.axvline(mc["nominal_um"][f], color="k", lw=1.5, label="nominal")
        ax.axvline(mc["percentiles_um"]["90"][f], color="tab:blue", ls="--", label="90th pct")
        if rss_um is not None:
            ax.axvline(rss_um[f], color="tab:red", ls=":", lw=2, label="RSS estimate")
        ax.set_title(f"field {mc['fields_deg'][f]:g} deg")
        ax.set_xlabel("RMS spot (µm)")
    axes[0, 0].set_ylabel(f"trials (of {mc['n']})")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return fig
