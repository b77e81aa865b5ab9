"""``deeplens design misalignment``: estimate a set-up's misalignment from a spot image by Eq. 15
(paper Sec. V-C, Fig. 17).  See :mod:`deeplens.design.misalignment` for the model.

Simulation (default): ``--truth tilt_x=..,tilt_y=..,d_sensor=..,source_x=..,source_y=..``
synthesises a noisy target from hidden values (names not given take
:data:`~deeplens.design.misalignment.DEFAULT_TRUTH`; tilts rad, lengths mm), then the five
parameters are estimated from ``--start`` (default
:data:`~deeplens.design.misalignment.DEFAULT_START`).  A captured image: ``--target IMAGE`` with
the set-up as options (``--resolution``, ``--pixel-size-um``, ``--source-distance``, ...).

Writes ``misalignment.png`` (target, start, estimate, difference) and
``misalignment_history.png`` (loss and parameters per step) into ``--out``.  Returns
``{"truth", "estimate", "abs_error", "start", "seconds", ...}`` (``truth`` and ``abs_error``
are ``null`` for a captured target).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

__all__ = ["add_arguments", "run"]


def _resolution(text: str):
    try:
        parts = [int(v) for v in str(text).lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 1:
        raise ValueError(f"--resolution: expected HxW pixels (e.g. 384x384), got {text!r}")
    return tuple(parts)


def add_arguments(parser) -> None:
    parser.add_argument("--truth", default=None,
                        help="hidden values NAME=VALUE,... of tilt_x, tilt_y (rad), d_sensor, "
                             "source_x, source_y (mm); default tilt_x=0.04,tilt_y=-0.03,"
                             "d_sensor=46.6,source_x=1.5,source_y=-1.0")
    parser.add_argument("--start", default=None,
                        help="coarse start NAME=VALUE,... (default: aligned, d_sensor=46.3)")
    parser.add_argument("--target", default=None,
                        help="a captured monochrome image (PNG/TIFF/.npy) of --resolution "
                             "pixels instead of a simulated one")
    parser.add_argument("--lens", default=None, help="lens file (default: the shipped LA1131)")
    parser.add_argument("--wavelength", type=float, default=622.0, help="LED wavelength, nm")
    parser.add_argument("--source-distance", type=float, default=1000.0,
                        help="iris to the lens's first vertex, mm (default 1000)")
    parser.add_argument("--iris-radius", type=float, default=0.4, help="iris radius, mm")
    parser.add_argument("--pixel-size-um", type=float, default=3.45, help="pixel pitch, µm")
    parser.add_argument("--resolution", default="384x384",
                        help="sensor pixels HxW around the axis (default 384x384)")
    parser.add_argument("--binning", type=int, default=4,
                        help="pixels summed per side into one working pixel (default 4)")
    parser.add_argument("--rays", type=int, default=120000,
                        help="rays per simulated image (default 120000)")
    parser.add_argument("--mu", type=float, default=1.0,
                        help="weight of the centroid term of Eq. 15 (pixels^-2)")
    parser.add_argument("--rounds", type=int, default=3, help="Adam + DLS rounds")
    parser.add_argument("--adam-steps", type=int, default=30, help="Adam steps per round")
    parser.add_argument("--dls-steps", type=int, default=4, help="DLS steps per round")
    parser.add_argument("--noise", type=float, default=1.0,
                        help="noise level of the synthetic target (1: shot noise of a "
                             "2000-electron peak + 1%% read noise; 0: none)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the ray samples")


def run(args) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from ..misalignment import (DEFAULT_START, DEFAULT_TRUTH, LA1131_PATH, PARAMS, SpotImager,
                                SpotSetup, eq15_residual, estimate, estimate_uncertainty,
                                load_target_image, parse_params, synthesize_target)

    t0 = time.perf_counter()
    if not args.mu >= 0:
        raise ValueError(f"--mu must be >= 0, got {args.mu}")
    for name in ("rounds", "adam_steps", "dls_steps"):
        if getattr(args, name) < 0:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 0")
    if not args.noise >= 0:
        raise ValueError(f"--noise must be >= 0, got {args.noise}")
    if args.target is not None and args.truth is not None:
        raise ValueError("--truth is for a simulated target; with --target IMAGE the values "
                         "are unknown (leave --truth out)")
    lens_path = LA1131_PATH if args.lens is None else args.lens
    if not Path(lens_path).is_file():
        raise ValueError(f"--lens: no such file {lens_path!r}")
    setup = SpotSetup(lens_path=lens_path, wavelength_nm=args.wavelength,
                      source_distance_mm=args.source_distance, iris_radius_mm=args.iris_radius,
                      pixel_size_mm=args.pixel_size_um * 1e-3,
                      resolution=_resolution(args.resolution), binning=args.binning,
                      n_rays=args.rays, seed=args.seed)
    setup.check()
    start = parse_params(args.start, "--start", DEFAULT_START)
    truth = None
    if args.target is None:
        truth = parse_params(args.truth, "--truth", DEFAULT_TRUTH)
        target = synthesize_target(setup, truth, noise=args.noise > 0,
                                   full_well=2000.0 / max(args.noise, 1e-12) ** 2,
                                   read_noise=0.01 * args.noise)
    else:
        target = load_target_image(args.target, setup)
    history: list = []
    est, fitted, _ = estimate(target, setup, start, mu=args.mu, rounds=args.rounds,
                              adam_steps=args.adam_steps, dls_steps_per_round=args.dls_steps,
                              history=history)
    unc = estimate_uncertainty(target, setup, est, mu=args.mu)
    for k, why in unc.not_identifiable.items():
        warnings.warn(f"design misalignment: {k} = {est[k]:.6g} is not identifiable from this "
                      f"spot image ({why}; standard deviation {unc.std[k]:.3g}): do not trust "
                      f"its value", RuntimeWarning, stacklevel=2)
    imager = SpotImager(setup)
    with torch.no_grad():
        img0 = imager(torch.tensor([start[k] for k in PARAMS], dtype=torch.float64))
        img0 = img0 * target.sum() / img0.sum().clamp_min(1e-30)
        loss_truth = None
        if truth is not None:  # the fit's own loss at the hidden values: its noise floor
            r = eq15_residual(imager(torch.tensor([truth[k] for k in PARAMS],
                                                  dtype=torch.float64)), target, args.mu)
            loss_truth = float(r @ r)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 4, figsize=(11, 3))
    vmax = float(target.max())
    for a, im, title in zip(ax, (target, img0, fitted, fitted - target),
                            ("target", "start", "estimate", "estimate - target")):
        if title.startswith("estimate -"):
            h = a.imshow(im.numpy(), cmap="RdBu_r", vmin=-0.2 * vmax, vmax=0.2 * vmax)
            fig.colorbar(h, ax=a, fraction=0.046)
        else:
            a.imshow(im.numpy(), cmap="gray", vmin=0, vmax=vmax)
        a.set_title(title)
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "misalignment.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(1, 2, figsize=(9, 3))
    ax[0].semilogy([h[2] for h in history])
    ax[0].set_xlabel("step (Adam, then DLS at the end of each round)")
    ax[0].set_ylabel("Eq. 15 loss")
    for k in PARAMS:
        v = [h[3][k] for h in history]
        ref = truth[k] if truth is not None else v[-1]
        ax[1].plot([x - ref for x in v], label=k)
    ax[1].set_ylabel("value - truth" if truth is not None else "value - estimate")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "misalignment_history.png", dpi=110)
    plt.close(fig)
    return {"truth": truth, "estimate": est, "start": start,
            "abs_error": None if truth is None else {k: abs(est[k] - truth[k]) for k in PARAMS},
            "loss_start": history[0][2] if history else None,
            "loss_final": history[-1][2] if history else None,
            "loss_at_truth": loss_truth,
            "uncertainty": unc.std, "correlation": unc.correlation,
            "not_identifiable": unc.not_identifiable, "residual_sigma": unc.sigma,
            "seconds": time.perf_counter() - t0,
            "figures": [str(out / "misalignment.png"), str(out / "misalignment_history.png")]}
