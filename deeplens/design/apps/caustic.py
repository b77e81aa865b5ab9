"""``deeplens design caustic``: a B-spline freeform whose irradiance reproduces a picture at two
screen distances (paper Fig. 14, Eq. 11).  See :mod:`deeplens.design.caustic` for the model.

Writes into ``--out``: ``caustic_states.png`` (per distance: target, intermediate irradiance,
final irradiance, freeform height map), ``caustic_states.npz`` (the same arrays),
``caustic_loss.png`` and the optimised plates as lens files ``caustic_D<distance>mm.json``.
Returns ``{"ssim": {"<D> mm": value}, "seconds", ...}``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

__all__ = ["add_arguments", "run"]


def _floats(text: str, option: str) -> list[float]:
    try:
        vals = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{option}: expected comma-separated numbers of mm, got {text!r}") \
            from None
    if not vals or not all(math.isfinite(v) and v > 0 for v in vals):
        raise ValueError(f"{option}: expected positive distances in mm, got {text!r}")
    return vals


def add_arguments(parser) -> None:
    parser.add_argument("--target", default="camera",
                        help="a grey image bundled with scikit-image (default: camera)")
    parser.add_argument("--distances", default="50,100",
                        help="screen distances from the freeform, mm (default: 50,100)")
    parser.add_argument("--resolution", type=int, default=64,
                        help="target and screen pixels per side (default: 64)")
    parser.add_argument("--control-points", type=int, default=67,
                        help="B-spline control points per side (default: 67)")
    parser.add_argument("--rays-per-pixel", type=int, default=2,
                        help="rays per screen pixel per side (default: 2, i.e. 4 per pixel)")
    parser.add_argument("--half-width", type=float, default=5.0,
                        help="half-width of the square beam and screen, mm (default: 5)")
    parser.add_argument("--steps", type=int, default=300, help="Adam steps per distance")
    parser.add_argument("--lr", type=float, default=1.0,
                        help="Adam step as the screen displacement it causes, pixels (default 1)")
    parser.add_argument("--smooth", type=float, default=0.01,
                        help="weight of the surface-curvature penalty that keeps rays from "
                             "crossing (default 0.01; 0: none)")
    parser.add_argument("--floor", type=float, default=0.1,
                        help="darkest target level as a fraction of the brightest (default 0.1:"
                             " a refractive caustic cannot make a pixel fully dark)")


def _check(args) -> list[float]:
    dists = _floats(args.distances, "--distances")
    if args.resolution < 8:
        raise ValueError(f"--resolution must be >= 8 pixels, got {args.resolution}")
    if args.control_points < 4:
        raise ValueError(f"--control-points must be >= 4, got {args.control_points}")
    if args.rays_per_pixel < 1:
        raise ValueError(f"--rays-per-pixel must be >= 1, got {args.rays_per_pixel}")
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    if not (args.half_width > 0 and args.lr > 0):
        raise ValueError("--half-width and --lr must be > 0")
    if not args.smooth >= 0:
        raise ValueError(f"--smooth must be >= 0, got {args.smooth}")
    if not 0 <= args.floor < 1:
        raise ValueError(f"--floor must lie in [0, 1), got {args.floor}")
    return dists


def run(args) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch
    from skimage.metrics import structural_similarity

    from ...optics.io import save_lens
    from ..caustic import load_target, optimize_caustic, sag_map

    dists = _check(args)
    t0 = time.perf_counter()
    target = load_target(args.target, args.resolution, floor=args.floor)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    snaps = sorted({0, args.steps // 10, args.steps // 3, args.steps})
    results, ssim, rows = {}, {}, []
    for D in dists:
        r = optimize_caustic(target, half_width_mm=args.half_width, distance_mm=D,
                             n_ctrl=args.control_points, rays_per_pixel=args.rays_per_pixel,
                             steps=args.steps, lr_px=args.lr, smooth=args.smooth,
                             snapshots=snaps)
        E = r["irradiance"].double()
        key = f"{D:g} mm"
        T = target.numpy()
        ssim[key] = float(structural_similarity(E.numpy(), T, data_range=float(T.max() - T.min())))
        lens = r["lens"].to(torch.float64)
        save_lens(lens, out / f"caustic_D{D:g}mm.json")
        sag = sag_map(lens, args.half_width)
        results[key] = {"loss_first": r["loss"][0], "loss_last": r["loss"][-1],
                        "sag_pv_mm": float(sag.max() - sag.min()), "seconds": r["seconds"]}
        rows.append((D, r, sag))

    # the intermediate states themselves, for re-plotting or a video
    import numpy as np

    np.savez_compressed(out / "caustic_states.npz", target=target.numpy(),
                        steps=np.array(snaps),
                        **{f"irradiance_D{D:g}": np.stack([r["snapshots"][k].double().numpy()
                                                           for k in snaps])
                           for D, r, _ in rows},
                        **{f"sag_mm_D{D:g}": sag.numpy() for D, _, sag in rows})

    # figure: one row per distance (target, states, height map), like the paper's Fig. 14
    ncol = 2 + len(snaps)
    fig, axes = plt.subplots(len(rows), ncol, figsize=(2.2 * ncol, 2.4 * len(rows)),
                             squeeze=False)
    vmax = float(target.max())
    for a, (D, r, sag) in zip(axes, rows):
        a[0].imshow(target.numpy(), cmap="gray", vmin=0, vmax=vmax)
        a[0].set_title("target")
        for c, k in enumerate(snaps):
            a[1 + c].imshow(r["snapshots"][k].double().numpy(), cmap="gray", vmin=0, vmax=vmax)
            a[1 + c].set_title(f"D = {D:g} mm, step {k}", fontsize=8)
        im = a[-1].imshow(sag.numpy() * 1e3, cmap="viridis")
        a[-1].set_title("freeform sag (µm)", fontsize=8)
        fig.colorbar(im, ax=a[-1], fraction=0.046)
        for ax in a:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "caustic_states.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(4, 3))
    for D, r, _ in rows:
        ax.semilogy(r["loss"], label=f"D = {D:g} mm")
    ax.set_xlabel("Adam step")
    ax.set_ylabel("smoothed MSE + curvature penalty")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "caustic_loss.png", dpi=110)
    plt.close(fig)
    return {"ssim": ssim, "seconds": time.perf_counter() - t0, "per_distance": results,
            "resolution": args.resolution, "control_points": args.control_points,
            "rays": (args.resolution * args.rays_per_pixel) ** 2, "steps": args.steps,
            "figures": [str(out / "caustic_states.png"), str(out / "caustic_loss.png")]}
