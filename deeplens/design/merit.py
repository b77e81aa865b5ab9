"""Merit functions as residual vectors (least-squares methods see their structure).

The merit is ``F = sum_i r_i^2`` over the concatenated residuals of its terms:

* spot (:class:`SpotMerit`), per field ``f`` and wavelength ``λ`` with weight ``w_fλ``, for each
  of the ``M_fλ`` rays of a fixed pupil pattern landing at ``p_m`` on the image plane:
  ``r_m = w_fλ (p_m - p_ref) / sqrt(M_fλ)``, so that the block's sum of squares is
  ``w_fλ^2 RMS_fλ^2``; ``p_ref`` is the centroid of the valid rays (``"centroid"``), where the
  real chief ray lands (``"chief"``), or the field's polychromatic centroid
  ``sum_λ w_fλ^2 c_fλ / sum_λ w_fλ^2`` shared by its wavelengths (``"polychromatic"``: lateral
  colour then counts, as in a polychromatic spot diagram);
* first-order targets (:class:`TargetMerit`): ``r = w (q - q*) / |q*|`` for ``q`` the paraxial
  EFL, BFL or F-number;
* distortion (:class:`DistortionMerit`): ``r_f = w (y_chief,f - κ tan θ_f) / (κ tan θ_f)``,
  ``κ`` the paraxial chief-ray scale (:func:`~deeplens.optics.paraxial.chief_ray_scale`);
* image / irradiance (:func:`image_residual`): ``r = (I - I*) / sqrt(N)`` and optionally
  ``sqrt(μ) (C(I) - C(I*))``, ``C`` the intensity centroid (paper Eq. 15).

Pupil sampling regions (paper Sec. III-E) are found by tracing in :meth:`SpotMerit.prepare` and
then held fixed (not differentiated) while the lens changes: rays are not re-aimed during a step.
A trial lens on which a ray that reached the image at preparation is vignetted raises
:class:`~deeplens.design.optimizers.Infeasible` (``strict_rays``), so a step never lowers the
merit by dropping rays.
"""

from __future__ import annotations

import math

import torch

from ..optics.paraxial import chief_ray_scale, paraxial
from ..analysis.spot import chief_ray, find_pupil, image_plane_z
from ..optics.camera import unpack
from ..optics.rays import Rays
from ..optics.sampling import field_rays, pupil_pattern
from .optimizers import Infeasible

__all__ = ["SpotMerit", "TargetMerit", "DistortionMerit", "Merit", "image_residual",
           "image_centroid"]


def _check_list(values, what, unit, lo=None, hi=None):
    vals = [float(v) for v in values]
    if not vals:
        raise ValueError(f"{what}: at least one value is needed")
    for v in vals:
        if not math.isfinite(v) or (lo is not None and v <= lo) or (hi is not None and v >= hi):
            raise ValueError(f"{what} must be finite numbers in {unit}"
                             f"{'' if lo is None else f' within ({lo:g}, {hi:g})'}, got {vals}")
    return vals


class SpotMerit:
    """RMS spot residuals over fields x wavelengths (module docstring).

    Args:
        fields_deg: field angles (deg); default the lens spec's.
        wavelengths_nm: wavelengths (nm); default the lens spec's.
        weights: ``(F, W)`` weights, a per-field list, or ``None`` (all 1).
        sampling: pupil pattern (``hexapolar:R``, ``grid:N``, ``random:N``).
        reference: ``"centroid"``, ``"chief"`` or ``"polychromatic"`` (module docstring).
        image_plane: ``"sensor"``, ``"paraxial"`` or a z position (mm).
        pupil: ``"traced"`` or ``"paraxial"`` pupil regions.
        shrink: the traced regions are scaled by this factor (< 1 leaves a margin so that a
            small lens change does not vignette the rim rays).
        strict_rays: raise :class:`Infeasible` when a prepared ray is lost.
        per_wavelength_pupil: find a region per field *and* wavelength (default: per field, at
            the lens's primary wavelength, shared by all wavelengths: 1/W of the cost).
        pupil_grid, pupil_bisections: the traced pupil search's grid and edge bisections.
    """

    def __init__(self, fields_deg=None, wavelengths_nm=None, weights=None,
                 sampling: str = "hexapolar:6", reference: str = "centroid",
                 image_plane="sensor", pupil: str = "traced", shrink: float = 0.98,
                 strict_rays: bool = True, per_wavelength_pupil: bool = False,
                 pupil_grid: int = 65, pupil_bisections: int = 24):
        if reference not in ("centroid", "chief", "polychromatic"):
            raise ValueError(f"spot reference must be 'centroid', 'chief' or 'polychromatic', "
                             f"got {reference!r}")
        if pupil not in ("traced", "paraxial"):
            raise ValueError(f"pupil must be 'traced' or 'paraxial', got {pupil!r}")
        if not 0 < shrink <= 1:
            raise ValueError(f"shrink must lie in (0, 1], got {shrink}")
        pupil_pattern(sampling)  # validates the string
        self.fields = None if fields_deg is None else _check_list(
            fields_deg, "fields", "degrees", -90, 90)
        self.waves = None if wavelengths_nm is None else _check_list(
            wavelengths_nm, "wavelengths", "nm", 0, math.inf)
        self.weights_in = weights
        self.sampling, self.reference, self.image_plane = sampling, reference, image_plane
        self.pupil, self.shrink, self.strict_rays = pupil, float(shrink), strict_rays
        self.regions = None
        self.per_wavelength_pupil = bool(per_wavelength_pupil)
        self.pupil_grid, self.pupil_bisections = int(pupil_grid), int(pupil_bisections)

    # ---------------------------------------------------------------- preparation
    def prepare(self, lens) -> "SpotMerit":
        """Find the pupil region (and chief-ray aim) of every field and wavelength on ``lens``
        as it is now, and the rays that reach the image; returns ``self``.  ``lens``: a Lens
        (default trace options) or a :class:`~deeplens.optics.camera.Camera` (its options
        reach every trace: pupil search, chief-ray aiming, the rays; so do they in
        :meth:`residuals` and :meth:`rms` given the camera)."""
        lens, _, options = unpack(lens, None, None, "SpotMerit.prepare")
        self.fields = list(lens.spec.fields_deg) if self.fields is None else self.fields
        self.waves = list(lens.spec.wavelengths_nm) if self.waves is None else self.waves
        F, W = len(self.fields), len(self.waves)
        w = self.weights_in
        if w is None:
            w = torch.ones(F, W, dtype=torch.float64)
        else:
            w = torch.as_tensor(w, dtype=torch.float64)
            if w.dim() == 1 and w.numel() == F:
                w = w[:, None].expand(F, W)
            if w.shape != (F, W) or bool((w < 0).any()) or not bool(torch.isfinite(w).all()):
                raise ValueError(f"spot weights must be {F} per-field values or an ({F}, {W}) "
                                 f"table of non-negative numbers, got shape {tuple(w.shape)}")
        self.weights = w.clone()
        dtype = lens.dtype
        self.unit = pupil_pattern(self.sampling, dtype=dtype)
        self.regions, self.masks, self.aims = {}, {}, {}
        with torch.no_grad():
            primary = float(lens.spec.primary_wavelength_nm)
            for f in self.fields:
                shared = None
                for wl in self.waves:
                    if self.per_wavelength_pupil or shared is None:
                        reg = find_pupil(lens, f, wl if self.per_wavelength_pupil else primary,
                                         self.pupil, grid=self.pupil_grid,
                                         bisections=self.pupil_bisections, options=options)
                        if self.pupil == "traced":
                            reg.rx *= self.shrink
                            reg.ry *= self.shrink
                        shared = reg
                    self.regions[(f, wl)] = shared
                    self.masks[(f, wl)] = self._trace(lens, f, wl, options).valid.clone()
                    if int(self.masks[(f, wl)].sum()) == 0:
                        raise ValueError(f"field {f:g} deg at {wl:g} nm: no ray reaches the image")
                    if self.reference == "chief":
                        self.aims[(f, wl)] = chief_ray(lens, f, wl, self.image_plane,
                                                       options=options)[1]
        return self

    def _bundle(self, lens, keys):
        """One ray bundle for several ``(field, wavelength)`` keys (one trace for all: the
        tracer's cost is mostly per call, not per ray), plus the slice of each key."""
        dtype = lens.dtype
        unit = self.unit.to(dtype)
        o, d, w, sl, k0 = [], [], [], {}, 0
        for f, wl in keys:
            reg = self.regions[(f, wl)]
            r = field_rays(lens, f, wl, reg.points(unit), reg.z)
            o.append(r.o)
            d.append(r.d)
            w.append(r.wavelength)
            sl[(f, wl)] = slice(k0, k0 + r.o.shape[0])
            k0 += r.o.shape[0]
        return Rays(torch.cat(o), torch.cat(d), torch.cat(w), normalize=False), sl

    def _trace(self, lens, f, wl, options=None):
        rays, _ = self._bundle(lens, [(f, wl)])
        return lens.trace_to_sensor(rays, z_image=image_plane_z(lens, self.image_plane),
                                    options=options)

    def _need(self):
        if self.regions is None:
            raise RuntimeError("SpotMerit.prepare(lens) must be called before evaluating it")

    def _blocks(self, lens, keys=None):
        """``{(f, λ): (deviations (M, 2) masked, valid mask, count, rms)}`` for ``keys``
        (default all), from one trace; ``lens`` may be a Camera (its options)."""
        lens, _, options = unpack(lens, None, None, "SpotMerit")
        self._need()
        keys = [(f, wl) for f in self.fields for wl in self.waves] if keys is None else keys
        rays, sl = self._bundle(lens, keys)
        z_img = image_plane_z(lens, self.image_plane)
        out = lens.trace_to_sensor(rays, z_image=z_img, options=options)
        if self.reference == "chief":
            dtype = lens.dtype
            o, d, w = [], [], []
            for f, wl in keys:
                xy = torch.tensor([[0.0, self.aims[(f, wl)]]], dtype=dtype)
                r = field_rays(lens, f, wl, xy, self.regions[(f, wl)].z)
                o.append(r.o), d.append(r.d), w.append(r.wavelength)
            chief = lens.trace_to_sensor(Rays(torch.cat(o), torch.cat(d), torch.cat(w),
                                              normalize=False), z_image=z_img,
                                         options=options)
        res = {}
        for k, (f, wl) in enumerate(keys):
            s = sl[(f, wl)]
            ok = out.valid[s]
            ref_ok = self.masks[(f, wl)]
            lost = ref_ok & ~ok
            if self.strict_rays and bool(lost.any()):
                raise Infeasible(f"{int(lost.sum())} of {int(ref_ok.sum())} rays of field "
                                 f"{f:g} deg at {wl:g} nm are vignetted or miss a surface",
                                 kind="vignetted")
            ok = ok & ref_ok
            n = ok.sum().clamp(min=1)
            pts = out.o[s, :2]
            okf = ok.unsqueeze(-1).to(pts.dtype)
            if self.reference != "chief":
                ref = (pts * okf).sum(0) / n
            else:
                if not bool(chief.valid[k]):
                    raise Infeasible(f"the chief ray of field {f:g} deg at {wl:g} nm is lost",
                                     kind="vignetted")
                ref = chief.o[k, :2]
            res[(f, wl)] = (pts, ok, n, ref, okf)
        refs = ({key: v[3] for key, v in res.items()} if self.reference != "polychromatic"
                else self._polychromatic_refs(res))
        for key, (pts, ok, n, _, okf) in res.items():
            dev = (pts - refs[key]) * okf
            res[key] = (dev, ok, n, torch.sqrt((dev * dev).sum() / n))
        return res

    def _polychromatic_refs(self, res):
        """Per field, the centroid of its blocks' centroids weighted by ``w_fλ^2`` (the point
        that minimises the field's weighted sum of squares), shared by its wavelengths."""
        refs = {}
        for f in {f for f, _ in res}:
            keys = [k for k in res if k[0] == f]
            i = self.fields.index(f)
            w2 = torch.stack([self.weights[i, self.waves.index(wl)] ** 2 for _, wl in keys])
            if float(w2.sum()) <= 0:
                w2 = torch.ones_like(w2)
            c = torch.stack([res[k][3] for k in keys])
            ref = (w2.to(c)[:, None] * c).sum(0) / w2.sum().to(c)
            refs.update({k: ref for k in keys})
        return refs

    def _block(self, lens, f, wl):
        return self._blocks(lens, [(f, wl)])[(f, wl)]

    # ---------------------------------------------------------------- evaluation
    def residuals(self, lens) -> torch.Tensor:
        """The residual vector ``(sum_fλ 2 M_fλ,)`` in mm (module docstring); ``lens``: a Lens
        or a Camera (its options are used)."""
        b = self._blocks(lens)
        out = []
        for i, f in enumerate(self.fields):
            for j, wl in enumerate(self.waves):
                dev, ok, n, _ = b[(f, wl)]
                out.append((self.weights[i, j].to(dev) * dev / torch.sqrt(n.to(dev))).reshape(-1))
        return torch.cat(out)

    def rms(self, lens) -> torch.Tensor:
        """RMS spot radii ``(F, W)`` in mm (differentiable)."""
        b = self._blocks(lens)
        return torch.stack([torch.stack([b[(f, wl)][3] for wl in self.waves])
                            for f in self.fields])


class TargetMerit:
    """A first-order target: ``quantity`` in ``efl``, ``bfl``, ``fno`` (paraxial, primary
    wavelength) equal to ``target``; residual ``weight (q - target) / |target|``."""

    QUANTITIES = ("efl", "bfl", "fno")

    def __init__(self, quantity: str, target: float, weight: float = 1.0):
        if quantity not in self.QUANTITIES:
            raise ValueError(f"target quantity must be one of {self.QUANTITIES}, got {quantity!r}")
        if not (math.isfinite(float(target)) and float(target) != 0):
            raise ValueError(f"{quantity} target must be a finite non-zero number, got {target!r}")
        self.quantity, self.target, self.weight = quantity, float(target), float(weight)

    def prepare(self, lens):
        return self

    def value(self, lens) -> torch.Tensor:
        """The paraxial quantity (no ray is traced); ``lens`` may be a Camera."""
        return getattr(paraxial(unpack(lens)[0]), self.quantity)

    def residuals(self, lens) -> torch.Tensor:
        q = self.value(lens)
        return (self.weight * (q - self.target) / abs(self.target)).reshape(1)


class DistortionMerit:
    """Relative distortion of the real chief ray at each field (module docstring)."""

    def __init__(self, fields_deg=None, wavelength_nm: float | None = None,
                 image_plane="sensor", weight: float = 1.0):
        self.fields = None if fields_deg is None else _check_list(
            fields_deg, "distortion fields", "degrees", -90, 90)
        self.wavelength, self.image_plane, self.weight = wavelength_nm, image_plane, float(weight)

    def prepare(self, lens):
        """Aim the chief rays on ``lens`` as it is now; ``lens``: a Lens or a
        :class:`~deeplens.optics.camera.Camera` (its options reach the aiming traces)."""
        lens, _, options = unpack(lens, None, None, "DistortionMerit.prepare")
        if self.fields is None:
            self.fields = [f for f in lens.spec.fields_deg if float(f) != 0.0]
        if not self.fields:
            raise ValueError("distortion needs at least one non-zero field")
        wl = float(lens.spec.primary_wavelength_nm if self.wavelength is None
                   else self.wavelength)
        self.wavelength = wl
        self.aims = [chief_ray(lens, f, wl, self.image_plane, options=options)[1]
                     for f in self.fields]
        return self

    def distortion(self, lens) -> torch.Tensor:
        """Relative distortion ``(F,)`` (dimensionless; x100 for percent); ``lens``: a Lens or a
        Camera (its options are used)."""
        lens, _, options = unpack(lens, None, None, "DistortionMerit.distortion")
        dtype = lens.dtype
        z_img = image_plane_z(lens, self.image_plane)
        kappa = chief_ray_scale(lens, z_img, self.wavelength)
        z_ep = float(paraxial(lens).entrance_pupil_z)
        out = []
        for f, yp in zip(self.fields, self.aims):
            xy = torch.tensor([[0.0, yp]], dtype=dtype)
            c = lens.trace_to_sensor(field_rays(lens, f, self.wavelength, xy, z_ep),
                                     z_image=z_img, options=options)
            if not bool(c.valid[0]):
                raise Infeasible(f"the chief ray of field {f:g} deg is lost", kind="vignetted")
            ideal = kappa * math.tan(math.radians(f))
            out.append((c.o[0, 1] - ideal) / ideal)
        return torch.stack(out)

    def residuals(self, lens) -> torch.Tensor:
        return self.weight * self.distortion(lens)


class Merit:
    """A sum of terms, each with ``prepare(lens)`` and ``residuals(lens) -> (m_k,)``; the merit
    value is ``sum r^2`` over all of them (constraints from :mod:`.constraints` are terms too).
    ``lens`` may be a :class:`~deeplens.optics.camera.Camera`: it is handed to every term, so
    its options reach every trace (the terms here and the constraints take a camera)."""

    def __init__(self, *terms):
        self.terms = [t for t in terms if t is not None]
        if not self.terms:
            raise ValueError("a merit function needs at least one term")

    def prepare(self, lens) -> "Merit":
        for t in self.terms:
            t.prepare(lens)
        return self

    def residuals(self, lens) -> torch.Tensor:
        return torch.cat([t.residuals(lens).reshape(-1) for t in self.terms])

    def __call__(self, lens) -> torch.Tensor:
        r = self.residuals(lens)
        return (r * r).sum()


def image_centroid(image: torch.Tensor) -> torch.Tensor:
    """Intensity centroid ``(..., 2)`` = ``(x, y)`` in pixels (column, row) of ``(..., H, W)``."""
    H, W = image.shape[-2:]
    ys = torch.arange(H, dtype=image.dtype, device=image.device)
    xs = torch.arange(W, dtype=image.dtype, device=image.device)
    tot = image.sum((-2, -1)).clamp(min=torch.finfo(image.dtype).tiny)
    cx = (image.sum(-2) * xs).sum(-1) / tot
    cy = (image.sum(-1) * ys).sum(-1) / tot
    return torch.stack([cx, cy], -1)


def image_residual(image: torch.Tensor, target: torch.Tensor, mu: float = 0.0) -> torch.Tensor:
    """Residuals of ``||I - I*||^2 / N + μ ||C(I) - C(I*)||^2`` (paper Eqs. 11 and 15).

    Args:
        image: rendered image ``(..., H, W)`` (differentiable).
        target: the target, same shape.
        mu: centroid weight (pixels^-2); ``0`` gives the plain MSE of Eq. 11.

    Returns:
        ``(N + 2 K,)`` residuals (``K`` images when ``mu > 0``), whose sum of squares is the
        loss above.

    Raises:
        ValueError: shapes differ, or ``mu`` is negative or not finite.
    """
    if not isinstance(image, torch.Tensor) or not isinstance(target, torch.Tensor):
        raise TypeError("image and target must be tensors")
    if image.shape != target.shape:
        raise ValueError(f"image {tuple(image.shape)} and target {tuple(target.shape)} must have "
                         f"the same shape")
    if not (math.isfinite(mu) and mu >= 0):
        raise ValueError(f"mu must be a finite number >= 0, got {mu!r}")
    target = target.to(image)
    r = ((image - target) / math.sqrt(image.numel())).reshape(-1)
    if mu > 0:
        dc = image_centroid(image) - image_centroid(target)
        r = torch.cat([r, math.sqrt(mu) * dc.reshape(-1)])
    return r
