"""When is the renderer's geometric PSF enough?  Geometric vs diffraction PSF at the sensor pixel.

For one object point, the renderer's PSF (:func:`deeplens.render.psf.psf`: rays splatted
bilinearly on the sensor's pixel grid around the ideal image point) is compared with the
diffraction PSF (:func:`deeplens.analysis.diffraction.psf_fft`, the pupil function's FFT)
brought to the same grid by the same bilinear splatting of its fine samples (so both see the
same pixel filter).  Reported: the total-variation distance ``TV = ½ Σ |P_geo - P_diff|`` of
the two kernels (each summing to 1; the fraction of the energy the geometric model puts in the
wrong pixels), and both kernels' peaks.  The EDOF lens gets a cubic phase plate of ``α`` waves at
the rim of the beam (``a (x³ + y³)`` on the XY-polynomial surface, ``(n - 1) a r³ = α λ``), the
kind of plate the EDOF experiment learns.  One wavelength (587.56 nm), on axis (and the
doublet's 20° edge), objects at the training depth.

    PYTHONPATH=. python benchmarks/bench_psf_model.py            # prints a markdown table
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deeplens.analysis.diffraction import psf_fft  # noqa: E402
from deeplens.analysis.wavefront import wavefront  # noqa: E402
from deeplens.optics.io import load_lens  # noqa: E402
from deeplens.render.psf import psf as geometric_psf  # noqa: E402
from deeplens.render.scene import IdealCamera  # noqa: E402
from deeplens.render.sensor import Sensor  # noqa: E402
from deeplens.render.splat import splat_bilinear  # noqa: E402

WL = 587.5618


def object_point(lens, field_deg, depth_mm):
    """The object point ``(X, Y)`` (mm) whose chief ray crosses the paraxial entrance-pupil
    centre at ``field_deg`` (the convention of :mod:`deeplens.analysis.wavefront`)."""
    from deeplens.optics.paraxial import paraxial

    z_obj = float(lens.z_vertices()[0]) - depth_mm
    z_ep = float(paraxial(lens).entrance_pupil_z)
    return 0.0, -math.tan(math.radians(field_deg)) * (z_ep - z_obj)


def diffraction_kernel(lens, sensor, field_deg, depth_mm, K, n):
    """The FFT PSF splatted on the sensor's pixels around the ideal image point ``(K, K)``."""
    p = psf_fft(lens, field_deg, WL, n=n)
    Y, X = torch.meshgrid(p.y, p.x, indexing="ij")
    x = (X + p.center[0]).reshape(-1)
    y = (Y + p.center[1]).reshape(-1)
    i, j = sensor.xy_to_pixel(x, y)
    s = IdealCamera(lens, sensor).object_scale(depth_mm)
    px, py = object_point(lens, field_deg, depth_mm)
    ci, cj = sensor.xy_to_pixel(torch.tensor(px / s, dtype=x.dtype),
                                torch.tensor(py / s, dtype=x.dtype))
    k = splat_bilinear(i - ci + K / 2, j - cj + K / 2, p.psf.reshape(-1), (K, K))
    return k / k.sum(), float(p.strehl)


def pupil_samples(lens, field_deg):
    """Pupil samples per side so that the wavefront changes by < 1/4 wave between neighbours
    (measured on a 64-sample grid), between 64 and 512."""
    w = wavefront(lens, field_deg, WL, n=64)
    W = w.opd.masked_fill(~w.mask, float("nan"))
    step = max(float((W[1:] - W[:-1]).abs().nan_to_num().max()),
               float((W[:, 1:] - W[:, :-1]).abs().nan_to_num().max()))
    return int(min(512, max(64, math.ceil(64 * step / 0.25)))), w


def compare(lens, pixel_mm, field_deg, depth_mm, K=None):
    lens.spec.object_distance_mm = depth_mm
    sensor = Sensor((64, 64), pixel_mm)
    pt = object_point(lens, field_deg, depth_mm)
    g = geometric_psf(lens, sensor, pt, depth_mm, WL, sampling="grid:400", kernel_size=K)
    K = g.shape[0]
    n, w = pupil_samples(lens, field_deg)
    d, strehl = diffraction_kernel(lens, sensor, field_deg, depth_mm, K, n)
    tv = 0.5 * float((g - d).abs().sum())
    return tv, float(g.max()), float(d.max()), K, float(w.rms), n


def main():
    rows = []
    t0 = time.time()
    edof = load_lens(ROOT / "data" / "lenses" / "edof_achromat.json").to(torch.float64)
    plate = edof.surfaces[4]
    n_glass = float(edof.materials[4].n(torch.tensor(WL, dtype=torch.float64)))
    r = 6.0  # mm, the beam's radius on the plate
    for alpha in (0.0, 1.0, 3.0, 10.0, 30.0):
        a = alpha * WL * 1e-6 / ((n_glass - 1) * r ** 3)
        with torch.no_grad():
            plate.a[6].fill_(a)   # y^3
            plate.a[9].fill_(a)   # x^3
        for pix in (0.0195, 0.0069, 0.0049):
            tv, pg, pd, K, rms, n = compare(edof, pix, 0.0, 6000.0)
            rows.append(("EDOF achromat + cubic plate", f"{alpha:g}", f"{pix * 1e3:.1f}", "0",
                         f"{rms:.2f}", n, K, f"{pg:.3f}", f"{pd:.3f}", f"{tv:.3f}"))
    doub = load_lens(ROOT / "data" / "lenses" / "wide_doublet.json").to(torch.float64)
    for field in (0.0, 10.0, 20.0):
        for pix in (0.0804,):
            tv, pg, pd, K, rms, n = compare(doub, pix, field, 10000.0)
            rows.append(("wide doublet (F/4)", "-", f"{pix * 1e3:.1f}", f"{field:g}", f"{rms:.2f}",
                         n, K, f"{pg:.3f}", f"{pd:.3f}", f"{tv:.3f}"))
    print("| lens | cubic α (waves) | pixel (µm) | field (°) | wavefront RMS (waves) | pupil N | "
          "K | peak geometric | peak diffraction | TV distance |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r_ in rows:
        print("| " + " | ".join(str(v) for v in r_) + " |")
    # the FFT PSF's own error at the doublet's edge: its spread against the rays' (the
    # geometric limit it must reach for a large wavefront error)
    from deeplens.analysis.wavefront import pupil_grid, trace_pupil

    doub.spec.object_distance_mm = 10000.0
    g = pupil_grid(256)
    g = g[(g ** 2).sum(-1) <= 1]
    tr = trace_pupil(doub, 20.0, WL, g)
    ray_sd = float(tr.points[tr.mask][:, 1].std()) * 1e3
    n, _ = pupil_samples(doub, 20.0)
    p = psf_fft(doub, 20.0, WL, n=n)
    yy = p.y[:, None].expand_as(p.psf)
    t = p.psf.sum()
    cy = (p.psf * yy).sum() / t
    fft_sd = float(torch.sqrt((p.psf * (yy - cy) ** 2).sum() / t)) * 1e3
    print(f"\nwide doublet, 20 deg: RMS spread in y of the rays {ray_sd:.1f} um, of the FFT PSF "
          f"{fft_sd:.1f} um")
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
