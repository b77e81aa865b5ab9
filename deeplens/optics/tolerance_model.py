"""Manufacturing tolerances as distributions, and lenses drawn from them.

A tolerance *group* (Hydra ``configs/tolerance/<name>.yaml``, also read by
``deeplens tolerance --group``; the files are read by
:func:`deeplens.design.tolerance_groups.load_group`, the model here takes a plain mapping) gives
one distribution per kind of error:

    radius     relative (ΔR/R) or in fringes N (Δc = N λ_f / h², h the semi-diameter)
    thickness  glass centre thickness (mm)      air_gap  air spacing (mm)
    index      n_d (absolute)                   abbe     V_d (relative, ΔV/V)
    decenter   element dx, dy (mm)              tilt     element tilt_x, tilt_y (rad)
    sensor     last-vertex-to-sensor distance (mm)

each as ``{shape: normal, std: σ, truncate: k}`` (a normal truncated at ±kσ) or
``{shape: uniform, half_width: t}`` (``σ = t/√3``), or ``null`` (not toleranced).  Every
parameter is drawn independently; a drawn lens is the nominal lens with

    c' = c / (1 + ε)  (relative)  or  c' = c + N λ_f / h²  (fringes);   p' = p + δ  (others)

applied as a differentiable function of the nominal values (:func:`drawn`), so gradients of
anything computed through a drawn lens reach the nominal parameters.  A glass of index n(λ)
becomes ``n_d + Δn + (n(λ) − n_d) / (1 + ε_V)`` (the dispersion n_F − n_C scales as 1/V).
``compensator: refocus`` moves the sensor by the change of the paraxial image distance of the
object (``lens.spec.object_distance_mm``) from the nominal lens to the drawn one (an assembler
refocusing each lens; differentiable in the nominal values), after the drawn sensor error.
``compensator: center`` (alone or in a list, ``[refocus, center]``) is the lateral half of an
active alignment: the whole lens (every element, stop included) moves across the axis, as a
barrel is centred on its sensor, until the image of the on-axis object point (the centroid of
its spot at the primary wavelength, a ``hexapolar:6`` bundle over 95 % of the paraxial entrance
pupil) lands where the nominal lens puts it.  A decentred element moves the whole image (the
doublet's 25 µm decenter moves it by 0.3–0.8 px, docs/results/doublet_tolerance.md); a camera
is calibrated or aligned for that, so without this compensator a tolerance test scores where
the image lands rather than how sharp it is.  The translation is found by three fixed-point steps
(each moves the lens by minus the remaining miss: a rigid translation moves the image by about
itself, by ``1 − m`` for a finite object of lateral magnification ``m``, and the probe bundle's
footprint on the moved lens changes the centroid slightly, so the miss shrinks by ~1e-2 or
better per step: 30 µm becomes ~2e-6 µm on the doublet in float64) and is differentiable in the nominal
values.  Centring runs after the refocus.

A draw is reproducible from its seed: :meth:`ToleranceModel.draw` uses its own
``torch.Generator`` and a fixed parameter order.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field

import torch

from .errors import ConfigError
from .materials import Air, Material
from .surfaces import Aperture

__all__ = ["KINDS", "COMPENSATORS", "Distribution", "ToleranceModel",
           "LensDraw", "PerturbedMaterial", "drawn", "call_drawn", "axis_image"]

#: the kinds of error a group may give, with their units
KINDS = {"radius": "relative or fringes", "thickness": "mm", "air_gap": "mm", "index": "n_d",
         "abbe": "relative", "decenter": "mm", "tilt": "rad", "sensor": "mm"}


def _num(v, where, lo=0.0, lo_open=False):
    what = f"a finite number {'>' if lo_open else '>='} {lo:g}"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(where, what, v)
    v = float(v)
    if not math.isfinite(v) or v < lo or (lo_open and v == lo):
        raise ConfigError(where, what, v)
    return v


@dataclass(frozen=True)
class Distribution:
    """A zero-mean distribution: ``normal`` (``std`` σ, truncated at ±``truncate`` σ) or
    ``uniform`` (in ±``half_width``)."""

    shape: str
    scale: float          # σ (normal) or half-width (uniform)
    truncate: float = math.inf

    @classmethod
    def from_config(cls, spec, where: str) -> "Distribution | None":
        """Parse ``{shape, std, truncate}`` / ``{shape, half_width}``; errors name ``where``."""
        if spec is None:
            return None
        if not isinstance(spec, dict):
            raise ConfigError(where, "a mapping {shape: normal|uniform, ...} or null", spec)
        spec = dict(spec)
        spec.pop("unit", None)
        shape = spec.pop("shape", None)
        allowed = {"normal": {"std", "truncate"}, "uniform": {"half_width"}}.get(shape, set())
        extra = set(spec) - allowed
        if allowed and extra:
            raise ConfigError.unknown(where, extra, ["shape", "unit", *sorted(allowed)])
        if shape == "normal":
            scale = _num(spec.get("std"), f"{where}.std")
            trunc = _num(spec.get("truncate", 3.0), f"{where}.truncate", 0.0, lo_open=True)
        elif shape == "uniform":
            scale = _num(spec.get("half_width"), f"{where}.half_width")
            trunc = math.inf
        else:
            raise ConfigError(f"{where}.shape", "'normal' or 'uniform'", shape)
        return cls(shape, scale, trunc)

    @property
    def std(self) -> float:
        """The standard deviation of the (truncated) distribution."""
        if self.shape == "uniform":
            return self.scale / math.sqrt(3.0)
        k = self.truncate
        if math.isinf(k):
            return self.scale
        phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
        mass = math.erf(k / math.sqrt(2))
        return self.scale * math.sqrt(1.0 - 2.0 * k * phi / mass)

    @property
    def bound(self) -> float:
        """The largest possible magnitude of a draw (``inf`` for an untruncated normal)."""
        return self.scale if self.shape == "uniform" else self.scale * self.truncate

    def sample(self, n: int, generator: torch.Generator) -> torch.Tensor:
        """``n`` float64 draws (inverse CDF of one uniform each, so each draw uses exactly one
        number of ``generator``)."""
        u = torch.rand(n, generator=generator, dtype=torch.float64)
        if self.shape == "uniform":
            return (2.0 * u - 1.0) * self.scale
        k = self.truncate
        lo = 0.5 * math.erfc(k / math.sqrt(2)) if math.isfinite(k) else 0.0
        p = (lo + u * (1.0 - 2.0 * lo)).clamp(1e-300, 1 - 1e-16)
        return torch.special.ndtri(p) * self.scale


class PerturbedMaterial(Material):
    """``base`` with ``n_d`` shifted by ``dn`` and ``V_d`` scaled by ``1 + eps_v``:
    ``n'(λ) = n_d + dn + (n(λ) − n_d) / (1 + eps_v)``.  ``dn``/``eps_v`` are buffers (so a
    render's geometry cache sees the change)."""

    def __init__(self, base: Material, dn: float, eps_v: float):
        super().__init__(f"{base.name}~", base.wavelength_range_nm)
        self.base = base
        self.n_d0 = base.nd
        self.register_buffer("dn", torch.tensor(float(dn), dtype=torch.float64))
        self.register_buffer("eps_v", torch.tensor(float(eps_v), dtype=torch.float64))

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        n = self.base.n(w)
        return (self.n_d0 + self.dn.to(n) + (n - self.n_d0) / (1.0 + self.eps_v.to(n)))

    def to_spec(self) -> str:
        return self.base.to_spec()


@dataclass
class LensDraw:
    """One drawn lens: ``relative`` ``{name: ε}`` (``p' = p / (1 + ε)``), ``offsets``
    ``{name: δ}`` (``p' = p + δ``), ``materials`` ``{medium index: (Δn, ε_V)}``, and the
    ``seed`` it came from.  ``compensate``: refocus the sensor (paraxial image distance);
    ``center``: centre the lens on the on-axis image (module docstring)."""

    seed: int
    relative: dict = field(default_factory=dict)
    offsets: dict = field(default_factory=dict)
    materials: dict = field(default_factory=dict)
    compensate: bool = False
    center: bool = False

    def values(self, lens) -> dict:
        """``{name: drawn value}`` as differentiable functions of the nominal parameters."""
        params = dict(lens.named_parameters())
        out = {}
        for n in set(self.relative) | set(self.offsets):
            p = params[n]
            v = p
            if n in self.relative:
                v = v / (1.0 + torch.as_tensor(self.relative[n], dtype=torch.float64).to(p))
            if n in self.offsets:
                v = v + torch.as_tensor(self.offsets[n], dtype=torch.float64).to(p)
            out[n] = v
        return out


#: the compensators a group may name (module docstring)
COMPENSATORS = ("refocus", "center")


def _compensators(spec, where: str) -> tuple[str, ...]:
    """``null`` / ``none`` / a name / a list of names -> the tuple of compensator names."""
    if spec is None or spec == "none":
        return ()
    what = f"null, one of {', '.join(COMPENSATORS)} or a list of them (each once)"
    names = [spec] if isinstance(spec, str) else spec
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
        raise ConfigError(where, what, spec)
    bad = [n for n in names if n not in COMPENSATORS]
    if bad or len(set(names)) != len(names):
        raise ConfigError(where, what, spec)
    return tuple(n for n in COMPENSATORS if n in names)


class ToleranceModel:
    """The distributions of one tolerance group (module docstring).

    Args:
        config: ``{kind: distribution or null, ..., compensator: null|refocus|center|[...],
            fringe_wavelength_nm: λ_f}``, kinds of :data:`KINDS`; ``radius`` also takes
            ``unit: relative|fringes``.
        where: the config key for error messages (``"tolerance"``).

    Raises:
        ConfigError: an unknown key, shape or unit, or a bad number; the message names the key.

    Example:
        >>> from deeplens.optics import load_lens
        >>> from deeplens.optics.paraxial import paraxial
        >>> lens = load_lens("double_gauss")
        >>> tm = ToleranceModel({"decenter": {"shape": "normal", "std": 0.01, "truncate": 2}})
        >>> d = tm.draw(lens, seed=3)
        >>> with drawn(lens, d):            # anything traced here sees the drawn lens
        ...     efl = paraxial(lens).efl    # (a decenter leaves the paraxial focal length)
        >>> round(float(efl), 2)
        27.44
    """

    def __init__(self, config: dict | None, where: str = "tolerance"):
        cfg = dict(config or {})
        self.where = where
        self.name = str(cfg.pop("name", "") or "")
        self.compensators = _compensators(cfg.pop("compensator", None), f"{where}.compensator")
        #: ``"refocus"`` when the sensor is refocused (kept for callers that read one name)
        self.compensator = "refocus" if "refocus" in self.compensators else None
        self.fringe_wavelength_nm = _num(cfg.pop("fringe_wavelength_nm", 632.8),
                                         f"{where}.fringe_wavelength_nm", 0.0, lo_open=True)
        unknown = set(cfg) - set(KINDS)
        if unknown:
            raise ConfigError.unknown(where, unknown, [*KINDS, "compensator",
                                                       "fringe_wavelength_nm", "name"])
        self.radius_unit = "relative"
        r = cfg.get("radius")
        if isinstance(r, dict) and "unit" in r:
            if r["unit"] not in ("relative", "fringes"):
                raise ConfigError(f"{where}.radius.unit", "'relative' or 'fringes'", r["unit"])
            self.radius_unit = r["unit"]
        self.dists = {k: Distribution.from_config(cfg.get(k), f"{where}.{k}") for k in KINDS}
        for k in ("radius", "abbe"):
            d = self.dists[k]
            if d is not None and not (k == "radius" and self.radius_unit == "fringes") \
                    and d.bound >= 0.5:
                raise ConfigError(f"{where}.{k}", f"a relative error bounded within +-0.5 "
                                  f"(truncate it; this one's bound is {d.bound:g})",
                                  cfg.get(k))

    def __bool__(self) -> bool:
        return any(d is not None and d.scale > 0 for d in self.dists.values())

    # ------------------------------------------------------------------ parameters
    def parameters_of(self, lens) -> list[tuple[str, str]]:
        """``[(kind, name)]``: every toleranced quantity of ``lens`` in draw order (names are
        parameter names, or ``materials.i`` for a glass medium's index and Abbe number)."""
        out = []
        for i, s in enumerate(lens.surfaces):
            if hasattr(s, "c") and not isinstance(s, Aperture):
                out.append(("radius", f"surfaces.{i}.c"))
        for i in range(1, len(lens.surfaces)):
            glass = not isinstance(lens.materials[i], Air)
            out.append(("thickness" if glass else "air_gap", f"distances.{i}"))
        for i, m in enumerate(lens.materials):
            if not isinstance(m, Air):
                out += [("index", f"materials.{i}"), ("abbe", f"materials.{i}")]
        for e, (a, b) in enumerate(lens.elements):
            glass = any(not isinstance(lens.materials[i + 1], Air) for i in range(a, b + 1))
            if glass:
                out += [("decenter", f"misalignments.{e}.dx"), ("decenter", f"misalignments.{e}.dy"),
                        ("tilt", f"misalignments.{e}.tilt_x"), ("tilt", f"misalignments.{e}.tilt_y")]
        out.append(("sensor", "d_sensor"))
        return out

    def draw(self, lens, seed: int) -> LensDraw:
        """The lens drawn by ``seed`` (every quantity consumes one number of a generator
        seeded by ``seed``, in :meth:`parameters_of` order, toleranced or not)."""
        g = torch.Generator().manual_seed(int(seed))
        d = LensDraw(seed=int(seed), compensate="refocus" in self.compensators,
                     center="center" in self.compensators)
        lam_mm = self.fringe_wavelength_nm * 1e-6
        for kind, name in self.parameters_of(lens):
            dist = self.dists[kind]
            x = 0.0 if dist is None else float(dist.sample(1, g))
            if dist is None:
                torch.rand(1, generator=g)
            if x == 0.0:
                continue
            if kind == "radius" and self.radius_unit == "relative":
                d.relative[name] = x
            elif kind == "radius":
                i = int(name.split(".")[1])
                h = float(lens.surfaces[i].semi_diameter)
                d.offsets[name] = x * lam_mm / (h * h)
            elif kind in ("index", "abbe"):
                i = int(name.split(".")[1])
                dn, ev = d.materials.get(i, (0.0, 0.0))
                d.materials[i] = (x, ev) if kind == "index" else (dn, x)
            else:
                d.offsets[name] = x
        return d

    def half_widths(self, lens) -> tuple[list[str], torch.Tensor]:
        """``(names, √3 σ)`` of the toleranced *parameters* (glass index and Abbe number are
        not parameters and are left out) in their units (1/mm for curvatures), for the RSS
        estimate of :mod:`.sensitivity` (which takes ``σ = half-width / √3``)."""
        names, t = [], []
        for kind, name in self.parameters_of(lens):
            dist = self.dists[kind]
            if dist is None or kind in ("index", "abbe"):
                continue
            s = dist.std
            if kind == "radius":
                i = int(name.split(".")[1])
                if self.radius_unit == "relative":
                    s *= abs(float(lens.surfaces[i].c))
                else:
                    s *= self.fringe_wavelength_nm * 1e-6 / float(lens.surfaces[i].semi_diameter) ** 2
            if s > 0:
                names.append(name)
                t.append(math.sqrt(3.0) * s)
        return names, torch.tensor(t, dtype=torch.float64)

    def draws(self, lens, n: int, seed: int = 0) -> list[LensDraw]:
        """``n`` draws with seeds ``seed, seed + 1, ...``."""
        return [self.draw(lens, seed + k) for k in range(int(n))]


@contextlib.contextmanager
def _swapped_materials(lens, draw: LensDraw):
    old = {}
    try:
        for i, (dn, ev) in draw.materials.items():
            old[i] = lens.materials[i]
            lens.materials[i] = PerturbedMaterial(old[i], dn, ev).to(lens.device)
        yield
    finally:
        for i, m in old.items():
            lens.materials[i] = m


def _image_distance(lens) -> torch.Tensor:
    from .paraxial import paraxial

    return paraxial(lens).image_distance


@contextlib.contextmanager
def drawn(lens, draw: LensDraw | None):
    """Within the block, ``lens`` *is* the drawn lens: its toleranced parameters are replaced
    by the drawn values (differentiable functions of the nominal ones), its glasses by
    :class:`PerturbedMaterial`, and with ``draw.compensate`` its sensor refocused.  Everything
    holding ``lens`` (renderer, camera) sees the drawn lens; on exit the nominal parameter
    objects are back, unchanged.  ``draw=None``: the nominal lens.  ``lens`` may be a
    :class:`~deeplens.optics.camera.Camera`: its lens is drawn, the centring traces run at its
    options, and the block gets the camera."""
    if draw is None:
        yield lens
        return
    from torch.nn.utils.stateless import _reparametrize_module

    from .camera import unpack

    given = lens
    lens, _, options = unpack(lens, None, None, "drawn")

    # the compensator: the sensor follows the paraxial image of the object (differentiably), after
    # the drawn sensor error; the image distance is measured with the drawn values and glasses
    nominal = _image_distance(lens) if draw.compensate else None
    target = axis_image(lens, options=options) if draw.center else None
    with _swapped_materials(lens, draw):
        values = draw.values(lens)
        with _reparametrize_module(lens, dict(values), strict=False):
            if draw.compensate:
                shift = (_image_distance(lens) - nominal).to(lens.d_sensor)
                values["d_sensor"] = values.get("d_sensor", lens.d_sensor) + shift
        if draw.center:
            params = dict(lens.named_parameters())  # the nominal parameters (no block open)
            for _ in range(3):
                with _reparametrize_module(lens, dict(values), strict=False):
                    miss = axis_image(lens, options=options) - target
                for e in range(len(lens.elements)):
                    for k, name in enumerate((f"misalignments.{e}.dx", f"misalignments.{e}.dy")):
                        values[name] = values.get(name, params[name]) - miss[k].to(params[name])
        with _reparametrize_module(lens, dict(values), strict=False):
            yield given


def axis_image(lens, sampling: str = "hexapolar:6", pupil_fill: float = 0.95,
               options=None) -> torch.Tensor:
    """``(2,)`` (mm): where ``lens`` images the on-axis object point (``lens.spec``'s object
    distance) on its sensor: the centroid of the rays that reach it, traced at the primary
    wavelength through ``sampling`` over ``pupil_fill`` of the paraxial entrance pupil;
    differentiable in the lens's parameters.  ``lens``: a Lens (traced with ``options``) or a
    :class:`~deeplens.optics.camera.Camera` (its options are used).

    Raises:
        ValueError: no ray of the bundle reaches the sensor."""
    from .camera import unpack
    from .sampling import point_source_rays

    lens, _, options = unpack(lens, None, options, "axis_image")

    rays = point_source_rays(lens, (0.0, 0.0), lens.spec.object_distance_mm,
                             lens.spec.primary_wavelength_nm, 0, sampling=sampling,
                             pupil_margin=pupil_fill)
    out = lens.trace_to_sensor(rays, options=options)
    ok = out.valid.unsqueeze(-1).to(out.o.dtype)
    if not bool(out.valid.any()):
        raise ValueError(f"compensator 'center': no ray of the on-axis bundle reaches the sensor "
                         f"of {lens.name or 'the lens'}")
    return (torch.nan_to_num(out.o[:, :2]) * ok).sum(0) / ok.sum()


def call_drawn(lens, draw: LensDraw | None, fn):
    """``fn(lens)`` evaluated on the drawn lens (:func:`drawn`; ``lens`` may be a camera, then
    ``fn`` gets the camera of the drawn lens)."""
    with drawn(lens, draw) as L:
        return fn(L)
