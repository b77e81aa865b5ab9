"""Figures of the analysis functions (matplotlib, imported lazily, styled by :mod:`.style`).

Each ``*_figure`` computes its data with the tensor-returning functions of this package (no
gradients) and returns a matplotlib ``Figure``; :data:`KINDS` maps the ``deeplens plot --kind``
names to them.  Fields in degrees, wavelengths in nm, image-plane quantities in µm or mm as
labelled.  Each takes a lens (traced with ``options``, ``None``: the defaults) or a
:class:`~deeplens.optics.camera.Camera` in its place (its options reach every trace).
"""

from __future__ import annotations


import torch

from ..optics.camera import unpack
from ..optics.frames import local_frames, to_global
from ..optics.sampling import DEFAULT_SAMPLING, field_rays
from ..optics.paraxial import paraxial
from ..optics.surfaces import CoordinateBreak
from ..optics.surfaces.base import in_closed_domain
from . import style

__all__ = ["layout_figure", "spot_figure", "fan_figure", "field_figure", "distortion_figure",
           "opd_figure", "psf_figure", "mtf_figure", "through_focus_figure", "mtf_field_figure",
           "ee_figure", "KINDS", "FREQ_KINDS", "plot"]


@style.styled
def layout_figure(lens, fields_deg=None, n_rays: int = 7, wavelength_nm: float | None = None,
                  options=None):
    """A y-z section of ``lens`` with meridional rays of each field; returns a matplotlib Figure.
    A folded lens (mirrors, coordinate breaks) is drawn in the global frame
    (:func:`~deeplens.optics.frames.local_frames`).  ``lens``: a Lens (its rays traced with
    ``options``) or a :class:`~deeplens.optics.camera.Camera` (its options are used)."""
    lens, _, options = unpack(lens, None, options, "layout_figure")
    fields = list(lens.spec.fields_deg if fields_deg is None else fields_deg)
    w = float(lens.spec.primary_wavelength_nm if wavelength_nm is None else wavelength_nm)
    fig, ax = style.figure(size=(8, 4))
    with torch.no_grad():
        dtype = lens.dtype
        z = lens.z_vertices().double().cpu()
        frames = [(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64))] * (
            len(lens.surfaces) + 1)
        if lens.folded():
            frames = [(a.double().cpu(), b.double().cpu()) for a, b in local_frames(lens)]

        def yz(k, zz, yy):  # local (y, z) of frame k -> global (z, y) for the plot
            p3 = torch.stack([torch.zeros_like(yy), yy, zz], -1).double()
            g = to_global(frames[k], p3)
            return g[..., 2].numpy(), g[..., 1].numpy()

        for i, s in enumerate(lens.surfaces if lens.folded() else ()):
            if isinstance(s, CoordinateBreak):
                continue
            R = float(s.semi_diameter)
            y = torch.linspace(-R, R, 101, dtype=dtype)
            zero = torch.zeros_like(y)
            sag = torch.where(in_closed_domain(s, zero, y), s.sag(zero, y), zero) if hasattr(s, "sag") \
                else zero
            zi = z[i].expand(2)
            if getattr(s, "type_name", "") == "aperture":
                ax.plot(*yz(i, zi, torch.tensor([R, R * 1.3])), "k-", lw=2)
                ax.plot(*yz(i, zi, torch.tensor([-R, -R * 1.3])), "k-", lw=2)
            else:
                ax.plot(*yz(i, z[i] + sag.double(), y.double()), "k-",
                        lw=2 if i in lens.mirrors else 1)
        if not lens.folded():   # glass elements filled, in the lens's own (global) frame
            _draw_elements(ax, lens, z)
        zs = lens.z_sensor().double().cpu().expand(2)
        h = lens.sensor_semi_diameter or float(max(s.semi_diameter for s in lens.surfaces))
        ax.plot(*yz(-1, zs, torch.tensor([-h, h], dtype=torch.float64)), "b-", lw=2)
        p = paraxial(lens, w)
        r_ep = 0.5 * float(p.entrance_pupil_diameter)
        for k, f in enumerate(fields):
            ys = torch.linspace(-r_ep, r_ep, n_rays, dtype=dtype)
            xy = torch.stack([torch.zeros_like(ys), ys], -1)
            rays = field_rays(lens, f, w, xy, float(p.entrance_pupil_z))
            out, hits = lens.trace(rays, record=True, options=options)
            # a virtual image plane (Lens.virtual_image): the rays' lines extended backwards
            # to it, drawn dashed from the last surface
            virtual = lens.virtual_image
            end = lens.propagate_to_z(out, lens.z_sensor(), backwards=virtual)
            # the start in frame 0, the hit on surface i in the frame after it, the end in the last
            pts = [(0, rays.o)] + [(i + 1, q) for i, q in enumerate(hits)] + [(-1, end.o)]
            pts = [yz(f, q[..., 2].double().cpu(), q[..., 1].double().cpu()) for f, q in pts]
            ok = end.valid
            for r in range(n_rays):
                if not bool(ok[r]):
                    continue
                real = pts[:-1] if virtual else pts
                ax.plot([float(q[0][r]) for q in real], [float(q[1][r]) for q in real], "-",
                        color=style.field_color(k), lw=0.6)
                if virtual:
                    ax.plot([float(q[0][r]) for q in pts[-2:]],
                            [float(q[1][r]) for q in pts[-2:]], "--",
                            color=style.field_color(k), lw=0.6)
    ax.set_aspect("equal")
    ax.grid(False)
    ax.set_xlabel("z (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(style.title(lens.name or "lens"))
    fig.tight_layout()
    return fig


def _profile(s, z0: float, h: float, dtype):
    """``(z, y)`` numpy arrays of a surface's y-z section from ``-h`` to ``h`` (the sag beyond
    the surface's own domain held at its last value)."""
    y = torch.linspace(-h, h, 101, dtype=dtype)
    zero = torch.zeros_like(y)
    sag = torch.where(in_closed_domain(s, zero, y), s.sag(zero, y), zero) if hasattr(s, "sag") else zero
    return (z0 + sag.double()).numpy(), y.double().numpy()


def _draw_elements(ax, lens, z) -> None:
    """Glass elements as closed, filled outlines (front profile, rim, back profile, rim; the
    smaller surface continued flat out to the larger one's rim, as lens drawings do), other
    surfaces as open profiles, the stop as two bars."""
    from ..optics.materials import Air

    n = len(lens.surfaces)
    dtype = lens.dtype
    glass = [not isinstance(lens.materials[i + 1], Air) for i in range(n)]
    drawn = set()
    for i in range(n - 1):
        if not glass[i]:
            continue
        a, b = lens.surfaces[i], lens.surfaces[i + 1]
        h = max(float(a.semi_diameter), float(b.semi_diameter))
        za, ya = _profile(a, float(z[i]), float(a.semi_diameter), dtype)
        zb, yb = _profile(b, float(z[i + 1]), float(b.semi_diameter), dtype)
        import numpy as np

        # outline: front top->bottom, flat step to the rim, across, back bottom->top, across
        zz = np.concatenate([[za[-1]], za[::-1], [za[0]], [zb[0]], zb, [zb[-1]], [za[-1]]])
        yy = np.concatenate([[h], ya[::-1], [-h], [-h], yb, [h], [h]])
        ax.fill(zz, yy, facecolor="#cfe3f3", edgecolor="k", lw=0.8, closed=True)
        drawn.update((i, i + 1))
    for i, s in enumerate(lens.surfaces):
        R = float(s.semi_diameter)
        if getattr(s, "type_name", "") == "aperture" or _flat_stop_in_air(lens, i):
            # a stop in air (an Aperture, or the flat surface that holds a clear aperture
            # narrower than the pupil's stop radius, zmx/seq readers' stop_clear): two bars
            # from its opening's rim outwards
            R = min(R, float(getattr(s, "clear_radius", R)))
            ax.plot([float(z[i])] * 2, [R, R * 1.3], "k-", lw=2)
            ax.plot([float(z[i])] * 2, [-R, -R * 1.3], "k-", lw=2)
        elif i not in drawn:
            zz, yy = _profile(s, float(z[i]), R, dtype)
            ax.plot(zz, yy, "k-", lw=1)


def _flat_stop_in_air(lens, i: int) -> bool:
    """Whether surface ``i`` is the stop, a flat surface with air on both sides that is not a
    mirror (an opening in a plane: drawn as the stop's bars, not as a profile)."""
    from ..optics.materials import Air

    s = lens.surfaces[i]
    return (i == lens.stop_index and i not in lens.mirrors
            and isinstance(lens.materials[i], Air) and isinstance(lens.materials[i + 1], Air)
            and _is_flat(s, lens.dtype))


def _is_flat(s, dtype) -> bool:
    """A surface whose sag is 0 along a radius to its semi-diameter (9 points)."""
    if not hasattr(s, "sag"):
        return False
    with torch.no_grad():
        r = torch.linspace(0, float(s.semi_diameter), 9, dtype=dtype)
        return bool((s.sag(torch.zeros_like(r), r) == 0).all())


def _fields(lens, fields_deg):
    return [float(f) for f in (lens.spec.fields_deg if fields_deg is None else fields_deg)]


def _waves(lens, wavelengths_nm):
    return [float(w) for w in (lens.spec.wavelengths_nm if wavelengths_nm is None
                               else wavelengths_nm)]


def _primary(lens, wavelengths_nm):
    if wavelengths_nm:
        return float(wavelengths_nm[0])
    return float(lens.spec.primary_wavelength_nm)


def _grid(n):
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    return rows, cols


def _axes_list(ax):
    import numpy as np

    return list(np.atleast_1d(ax).ravel())


def _field_panels(n: int, width: float, height: float):
    """A figure of ``n`` panels (up to 4 per row), each ``width`` x ``height`` inches, the
    unused grid cells hidden; returns ``(fig, axes)`` with the ``n`` panels in order."""
    rows, cols = _grid(n)
    fig, ax = style.figure(rows, cols, size=(width * cols, height * rows + 0.4), squeeze=False)
    axes = _axes_list(ax)
    for a in axes[n:]:
        a.set_visible(False)
    return fig, axes[:n]


def _diffraction_fields(lens, fields, waves, image_plane, options, explicit: bool):
    """The fields a diffraction figure can draw, and a note on those it leaves out: a field
    whose marginal rays miss a surface at one of ``waves`` has no pupil-to-frequency scale
    (:func:`~.diffraction.frequency_steps`; the shipped Cooke triplet's 11.86 deg edge field).
    Fields the user named (``explicit``) are not left out: their error is raised.

    Raises:
        AnalysisError: an ``explicit`` field that cannot be drawn, or no field left.
    """
    from .checks import AnalysisError
    from .diffraction import frequency_steps

    keep, dropped, why = [], [], ""
    for f in fields:
        try:
            for w in waves:
                frequency_steps(lens, f, w, 16, image_plane=image_plane, options=options)
            keep.append(f)
        except AnalysisError as e:
            if explicit:
                raise
            dropped.append(f)
            why = why or str(e)
    if not keep:
        raise AnalysisError(why)
    note = (f" (left out: {', '.join(f'{f:g}' for f in dropped)} deg, their marginal rays "
            f"miss a surface)" if dropped else "")
    return keep, note


def _title(fig, lens, what):
    """The figure's title: what it shows, then the lens's whole name (wrapped, never cut)."""
    width = max(40, int(fig.get_figwidth() * 14))   # ~14 characters per inch at 7 pt
    fig.suptitle(f"{what}\n{style.title(lens.name or 'lens', width)}", fontsize=7)


@style.styled
def spot_figure(lens, fields_deg=None, wavelengths_nm=None, sampling: str = DEFAULT_SAMPLING,
                image_plane="sensor", pupil: str = "traced", options=None):
    """Spot diagrams (µm), one panel per field, all panels on one scale, with the Airy circle.

    Points are plotted about the primary wavelength's centroid.  The RMS radius printed per
    wavelength is about that wavelength's own centroid, over the traced pupil with the same
    sampling as ``deeplens report`` (so the two agree; :func:`~.spot.spot_diagram`).  The circle
    is the Airy radius ``1.22 λ N_w`` at the primary wavelength, ``N_w`` the on-axis working
    F-number.  ``fig.deeplens_data["rms_um"][(field, wavelength)]`` holds the printed values.
    """
    from .cardinal import pupils
    from .spot import spot_diagram

    lens, _, options = unpack(lens, None, options, "spot_figure")
    fields, waves = _fields(lens, fields_deg), _waves(lens, wavelengths_nm)
    prim = _primary(lens, wavelengths_nm)
    fig, axes = _field_panels(len(fields), 2.4, 2.6)
    rms_um, extent = {}, 0.0
    with torch.no_grad():
        airy_um = 1.22 * prim * 1e-6 * float(pupils(lens, prim).working_fno) * 1e3
        for a, f in zip(axes, fields):
            ref = spot_diagram(lens, f, prim, sampling, pupil=pupil,
                               image_plane=image_plane, options=options).centroid
            lines = []
            for w in waves:
                s = spot_diagram(lens, f, w, sampling, pupil=pupil, image_plane=image_plane,
                                 options=options)
                d = (s.points - ref).double().cpu().numpy() * 1e3
                a.plot(d[:, 0], d[:, 1], ".", ms=1.2, color=style.wavelength_color(w),
                       label=f"{w:g} nm")
                rms_um[(f, w)] = float(s.rms_radius) * 1e3
                extent = max(extent, float(abs(d).max()))
                lines.append(f"{w:g} nm: {rms_um[(f, w)]:.3g}")
            circle = style.circle(airy_um)
            a.plot(*circle, "k-", lw=0.6)
            a.set_title(f"{f:g} deg")
            a.text(0.02, 0.02, "RMS (µm)\n" + "\n".join(lines), transform=a.transAxes,
                   fontsize=5.5, va="bottom", ha="left", color="0.2")
            a.set_xlabel("x (µm)")
    half = 1.08 * max(extent, airy_um)
    for a in axes:   # one scale for every field
        a.set_xlim(-half, half)
        a.set_ylim(-half, half)
        a.set_aspect("equal", adjustable="box")
    axes[0].set_ylabel("y (µm)")
    axes[0].legend(markerscale=6, loc="upper right")
    _title(fig, lens, f"spot diagram: RMS radius about each wavelength's own centroid, {pupil} "
                      f"pupil, {sampling} (as deeplens report)\ncircle: Airy radius "
                      f"{airy_um:.3g} µm (1.22 λ N_w at {prim:g} nm)")
    fig.deeplens_data = {"rms_um": rms_um, "airy_um": airy_um, "half_width_um": half}
    return fig


@style.styled
def fan_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor", n: int = 41,
               options=None):
    """Ray fans: tangential ``e_y(p_y)`` and sagittal ``e_x(p_x)`` in µm, one row per field,
    every panel on one shared scale (so the fields and the two sections compare by eye)."""
    from .aberrations import ray_fan

    lens, _, options = unpack(lens, None, options, "fan_figure")
    fields, waves = _fields(lens, fields_deg), _waves(lens, wavelengths_nm)
    fig, ax = style.figure(len(fields), 2, size=(6, 1.6 * len(fields) + 0.6), squeeze=False,
                           sharex=True, sharey=True)
    with torch.no_grad():
        for r, f in enumerate(fields):
            fan = ray_fan(lens, f, waves, n=n, image_plane=image_plane, options=options)
            p = fan.p.cpu().numpy()
            for w in waves:
                c = style.wavelength_color(w)
                ax[r, 0].plot(p, fan.ey[w].cpu().numpy() * 1e3, color=c, label=f"{w:g} nm")
                ax[r, 1].plot(p, fan.ex[w].cpu().numpy() * 1e3, color=c)
            ax[r, 0].set_ylabel(f"{f:g} deg\ne (µm)")
            for a in ax[r]:
                a.axhline(0, color="k", lw=0.5)
    ax[0, 0].set_title("tangential  e_y(p_y)")
    ax[0, 1].set_title("sagittal  e_x(p_x)")
    ax[-1, 0].set_xlabel("p_y")
    ax[-1, 1].set_xlabel("p_x")
    ax[0, 0].legend()
    _title(fig, lens, "ray fans")
    return fig


def _field_axis(lens, fields_deg, n=9):
    fields = _fields(lens, fields_deg)
    fmax = max(abs(f) for f in fields)
    return [fmax * k / (n - 1) for k in range(n)]


@style.styled
def field_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor", options=None):
    """Field curvature: tangential (solid) and sagittal (dashed) focus vs field, mm."""
    from .aberrations import field_curvature

    lens, _, options = unpack(lens, None, options, "field_figure")
    fs = _field_axis(lens, fields_deg)
    fig, ax = style.figure(size=(4, 3.5))
    with torch.no_grad():
        for w in _waves(lens, wavelengths_nm):
            zt, zs = field_curvature(lens, fs, w, image_plane=image_plane, options=options)
            c = style.wavelength_color(w)
            ax.plot(zt.cpu().numpy(), fs, "-", color=c, label=f"T {w:g} nm")
            ax.plot(zs.cpu().numpy(), fs, "--", color=c, label=f"S {w:g} nm")
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("focus - image plane (mm)")
    ax.set_ylabel("field (deg)")
    ax.legend()
    _title(fig, lens, "field curvature")
    return fig


@style.styled
def distortion_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
                      options=None):
    """Distortion (%) vs field, f-tan convention."""
    from .aberrations import distortion

    lens, _, options = unpack(lens, None, options, "distortion_figure")
    fs = _field_axis(lens, fields_deg)[1:]
    fig, ax = style.figure(size=(4, 3.5))
    with torch.no_grad():
        for w in _waves(lens, wavelengths_nm):
            d = distortion(lens, fs, w, image_plane=image_plane, options=options)
            ax.plot(d.cpu().numpy(), fs, color=style.wavelength_color(w), label=f"{w:g} nm")
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("distortion (%)")
    ax.set_ylabel("field (deg)")
    ax.set_ylim(0, None)
    ax.legend()
    _title(fig, lens, "distortion")
    return fig


@style.styled
def opd_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor", n: int = 64,
               options=None):
    """OPD maps (waves) over the normalised pupil, one panel per field, primary wavelength."""
    from .wavefront import wavefront

    lens, _, options = unpack(lens, None, options, "opd_figure")
    fields, w = _fields(lens, fields_deg), _primary(lens, wavelengths_nm)
    fig, axes = _field_panels(len(fields), 2.6, 2.4)
    with torch.no_grad():
        for a, f in zip(axes, fields):
            wf = wavefront(lens, f, w, n=n, image_plane=image_plane, options=options)
            m = wf.opd.masked_fill(~wf.mask, float("nan")).cpu().numpy()
            im = a.imshow(m, origin="lower", extent=(-1, 1, -1, 1), cmap="RdBu_r")
            fig.colorbar(im, ax=a, fraction=0.046, pad=0.04)
            a.set_title(f"{f:g} deg: RMS {float(wf.rms):.3f}, PV {float(wf.pv):.2f} waves")
            a.set_xlabel("p_x")
            a.grid(False)
    axes[0].set_ylabel("p_y")
    _title(fig, lens, f"OPD at {w:g} nm (waves)")
    return fig


@style.styled
def psf_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
               n: int | None = None,
               half_width_um: float | None = None, options=None):
    """Diffraction (FFT) PSFs, Strehl-normalised, one panel per field, primary wavelength."""
    from .diffraction import psf_fft

    lens, _, options = unpack(lens, None, options, "psf_figure")
    fields, w = _fields(lens, fields_deg), _primary(lens, wavelengths_nm)
    with torch.no_grad():
        fields, note = _diffraction_fields(lens, fields, [w], image_plane, options,
                                           fields_deg is not None)
    fig, axes = _field_panels(len(fields), 2.4, 2.4)
    with torch.no_grad():
        for a, f in zip(axes, fields):
            p = psf_fft(lens, f, w, n=n, image_plane=image_plane, options=options)
            x, y = p.x.cpu().numpy() * 1e3, p.y.cpu().numpy() * 1e3
            hw = half_width_um or 0.25 * float(x.max())
            a.imshow(p.psf.cpu().numpy(), origin="lower", extent=(x[0], x[-1], y[0], y[-1]))
            a.set_xlim(-hw, hw)
            a.set_ylim(-hw, hw)
            a.set_title(f"{f:g} deg, Strehl {float(p.strehl):.3f}")
            a.set_xlabel("x (µm)")
            a.grid(False)
    axes[0].set_ylabel("y (µm)")
    _title(fig, lens, f"PSF at {w:g} nm{note}")
    return fig


def _cutoff(lens, w):
    """Incoherent cut-off ``1 / (λ N_w)`` (cycles/mm) at ``w`` nm, on-axis working F-number."""
    from .cardinal import pupils

    return 1.0 / (w * 1e-6 * float(pupils(lens, w).working_fno))


def _default_freqs(nu_c):
    """Three frequencies for through-focus / field plots: ~10, 25 and 50 % of the cut-off,
    rounded to two significant figures (cycles/mm)."""
    import math

    def r2(v):
        k = math.floor(math.log10(v)) - 1
        return round(v / 10 ** k) * 10 ** k
    return [float(r2(f * nu_c)) for f in (0.1, 0.25, 0.5)]


def _wave_label(waves):
    return (f"{waves[0]:g} nm" if len(waves) == 1 else
            "polychromatic " + "/".join(f"{w:g}" for w in waves) + " nm, equal weights")


@style.styled
def mtf_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
               n: int | None = None, points: int = 41, options=None):
    """Diffraction MTF over all the given wavelengths (polychromatic,
    :func:`~.mtf_poly.polychromatic_mtf`), tangential (solid) and sagittal (dashed) per
    field, with the aberration-free limit at the primary wavelength (grey)."""
    import numpy as np

    from .mtf_poly import polychromatic_mtf

    lens, _, options = unpack(lens, None, options, "mtf_figure")
    fields, waves = _fields(lens, fields_deg), _waves(lens, wavelengths_nm)
    w = _primary(lens, wavelengths_nm)
    fig, ax = style.figure(size=(5, 3.5))
    with torch.no_grad():
        fields, note = _diffraction_fields(lens, fields, waves, image_plane, options,
                                           fields_deg is not None)
        nu_c = _cutoff(lens, w)
        v = np.linspace(0, 1, 101)
        ax.plot(v * nu_c, 2 / np.pi * (np.arccos(v) - v * np.sqrt(1 - v * v)), color="0.6",
                label=f"diffraction limit {w:g} nm")
        freqs = torch.linspace(0, nu_c, points, dtype=torch.float64)
        for k, f in enumerate(fields):
            m = polychromatic_mtf(lens, f, freqs, waves, direction="both", n=n,
                                  image_plane=image_plane, options=options)
            c = style.field_color(k)
            ax.plot(freqs.numpy(), m[0].numpy(), "-", color=c, label=f"{f:g} deg T")
            ax.plot(freqs.numpy(), m[1].numpy(), "--", color=c, label=f"{f:g} deg S")
    ax.set_xlim(0, nu_c)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("spatial frequency (cycles/mm)")
    ax.set_ylabel("MTF")
    ax.legend(ncol=2)
    _title(fig, lens, f"diffraction MTF, {_wave_label(waves)}{note}")
    return fig


@style.styled
def through_focus_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
                         n: int | None = None, freqs=None, defocus_mm=None, options=None):
    """Through-focus MTF: polychromatic diffraction MTF at a few frequencies (default ~10, 25,
    50 % of the cut-off) against the image-plane shift (default ±4 λ N_w², 11 planes), one
    panel per field; T solid, S dashed."""
    import numpy as np

    from .mtf_poly import through_focus_mtf

    lens, _, options = unpack(lens, None, options, "through_focus_figure")
    fields, waves = _fields(lens, fields_deg), _waves(lens, wavelengths_nm)
    w = _primary(lens, wavelengths_nm)
    with torch.no_grad():
        fields, note = _diffraction_fields(lens, fields, waves, image_plane, options,
                                           fields_deg is not None)
        nu_c = _cutoff(lens, w)
        freqs = _default_freqs(nu_c) if freqs is None else [float(f) for f in freqs]
        if defocus_mm is None:
            dz = 4 * w * 1e-6 * (1.0 / (w * 1e-6 * nu_c)) ** 2
            defocus_mm = np.linspace(-dz, dz, 11)
        dz = np.asarray(defocus_mm, dtype=float)
        fig, axes = _field_panels(len(fields), 2.8, 2.4)
        data = {}
        for a, f in zip(axes, fields):
            m = through_focus_mtf(lens, f, freqs, dz, waves, direction="both", n=n,
                                  image_plane=image_plane, options=options)
            data[f] = m
            for j, nu in enumerate(freqs):
                c = style.field_color(j)
                a.plot(dz * 1e3, m[:, 0, j].numpy(), "-", color=c, label=f"{nu:g} c/mm T")
                a.plot(dz * 1e3, m[:, 1, j].numpy(), "--", color=c, label=f"{nu:g} c/mm S")
            a.set_title(f"{f:g} deg")
            a.set_ylim(0, 1.02)
            a.set_xlabel("focus shift (µm)")
            a.axvline(0, color="k", lw=0.5)
    axes[0].set_ylabel("MTF")
    axes[0].legend(fontsize=5.5)
    _title(fig, lens, f"through-focus MTF, {_wave_label(waves)}{note}")
    fig.deeplens_data = {"freqs": freqs, "defocus_mm": dz, "mtf": data}
    return fig


@style.styled
def mtf_field_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
                     n: int | None = None, freqs=None, points: int = 7, options=None):
    """Polychromatic diffraction MTF at a few frequencies (default ~10, 25, 50 % of the
    cut-off) against the field angle, from 0 to the largest field in ``points`` steps; T solid,
    S dashed."""
    from .mtf_poly import mtf_vs_field

    lens, _, options = unpack(lens, None, options, "mtf_field_figure")
    waves = _waves(lens, wavelengths_nm)
    w = _primary(lens, wavelengths_nm)
    fs = _field_axis(lens, fields_deg, points)
    fig, ax = style.figure(size=(5, 3.5))
    with torch.no_grad():
        fs, note = _diffraction_fields(lens, fs, waves, image_plane, options, False)
        freqs = _default_freqs(_cutoff(lens, w)) if freqs is None else [float(f) for f in freqs]
        m = mtf_vs_field(lens, fs, freqs, waves, direction="both", n=n, image_plane=image_plane,
                         options=options)
        for j, nu in enumerate(freqs):
            c = style.field_color(j)
            ax.plot(fs, m[:, 0, j].numpy(), "-", color=c, label=f"{nu:g} c/mm T")
            ax.plot(fs, m[:, 1, j].numpy(), "--", color=c, label=f"{nu:g} c/mm S")
    ax.set_xlabel("field (deg)")
    ax.set_ylabel("MTF")
    ax.set_ylim(0, 1.02)
    ax.set_xlim(0, max(fs))
    ax.legend(ncol=2)
    _title(fig, lens, f"MTF vs field, {_wave_label(waves)}{note}")
    fig.deeplens_data = {"fields_deg": fs, "freqs": freqs, "mtf": m}
    return fig


@style.styled
def ee_figure(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor",
              n: int | None = None, options=None):
    """Diffraction encircled energy vs radius (µm) per field."""
    import numpy as np

    from .diffraction import encircled_energy

    lens, _, options = unpack(lens, None, options, "ee_figure")
    fields, w = _fields(lens, fields_deg), _primary(lens, wavelengths_nm)
    fig, ax = style.figure(size=(5, 3.5))
    with torch.no_grad():
        fields, note = _diffraction_fields(lens, fields, [w], image_plane, options,
                                           fields_deg is not None)
        airy = 1.22 / _cutoff(lens, w)
        r = np.linspace(0, 8 * airy, 81)
        for k, f in enumerate(fields):
            ee = encircled_energy(lens, f, r, w, n=n, image_plane=image_plane, options=options)
            ax.plot(r * 1e3, ee.cpu().numpy(), color=style.field_color(k), label=f"{f:g} deg")
    ax.axvline(airy * 1e3, color="0.6", lw=0.8, ls=":", label="Airy radius")
    ax.set_xlabel("radius (µm)")
    ax.set_ylabel("encircled energy")
    ax.set_ylim(0, 1.02)
    ax.legend()
    _title(fig, lens, f"encircled energy at {w:g} nm{note}")
    return fig


def _layout(lens, fields_deg=None, wavelengths_nm=None, image_plane="sensor", options=None):
    lens, _, options = unpack(lens, None, options, "layout_figure")
    return layout_figure(lens, fields_deg, wavelength_nm=_primary(lens, wavelengths_nm),
                         options=options)


KINDS = {"layout": _layout, "spot": spot_figure, "fan": fan_figure, "field": field_figure,
         "distortion": distortion_figure, "opd": opd_figure, "psf": psf_figure,
         "mtf": mtf_figure, "through-focus": through_focus_figure,
         "mtf-field": mtf_field_figure, "ee": ee_figure}

#: kinds that take ``freqs`` (cycles/mm)
FREQ_KINDS = ("through-focus", "mtf-field")


def plot(lens, kind: str, path, fields_deg=None, wavelengths_nm=None,
         image_plane="sensor", dpi: float | None = None, freqs=None, options=None,
         sampling: str | None = None) -> None:
    """Draw figure ``kind`` (a key of :data:`KINDS`) and save it at ``path`` in the format its
    suffix names (vector for .pdf/.svg/.eps/.ps; :func:`.style.save`), ``dpi`` for rasters;
    ``freqs`` (cycles/mm) for the kinds of :data:`FREQ_KINDS`; ``sampling`` (the pupil
    pattern) for ``spot`` (other kinds draw their own rays and ignore it).  ``lens``: a Lens (traced with
    ``options``) or a :class:`~deeplens.optics.camera.Camera` (its options are used)."""
    if kind not in KINDS:
        raise ValueError(f"plot kind must be one of {'|'.join(KINDS)}, got {kind!r}")
    extra = {}
    if freqs is not None:
        if kind not in FREQ_KINDS:
            raise ValueError(f"frequencies apply to the kinds {', '.join(FREQ_KINDS)}, not "
                             f"{kind!r}")
        extra["freqs"] = freqs
    if sampling is not None and kind == "spot":
        extra["sampling"] = sampling
    lens, _, options = unpack(lens, None, options, "plot")
    fig = KINDS[kind](lens, fields_deg, wavelengths_nm, image_plane=image_plane,
                      options=options, **extra)
    style.save(fig, path, dpi=dpi)
