"""Mutation check: plant plausible bugs in a copy of the package, one at a time, and report
which ones the tests miss.

    python tests/mutation/run_mutations.py            # each bug against its relevant tests
    python tests/mutation/run_mutations.py --full     # each bug against the default suite
    python tests/mutation/run_mutations.py --only psnr_20log --only cos4_to_cos2
    python tests/mutation/run_mutations.py --list

The repository (without .git, .venv and outputs) is copied to a temporary directory; for each
entry of :data:`MUTATIONS` one text replacement is applied there, the tests run in that copy
(``python -m pytest -x -q``, default markers, so slow tests stay out) and the file is restored.
A bug is *caught* when pytest fails.  The copy is first checked clean (its tests pass), so a
catch is never a broken environment.  A mutation whose text is no longer in the file (the code
moved on) is reported as ``stale``: update its text, don't drop it.  Prints a markdown table;
the exit status is 1 when a bug is missed or stale.

Not collected by pytest (no ``test_`` prefix) and not part of CI: run it when adding a
capability, and add the bugs a reviewer would plausibly write for it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
IGNORE = shutil.ignore_patterns(".git", ".venv", "outputs", "logs", "__pycache__", "*.egg-info",
                                ".pytest_cache", "lightning_logs", "multirun")

RENDER = ("tests/render",)
OPTICS = ("tests/optics",)
TABLES = ("tests/optics/io",)
NOISE = ("tests/render/test_sensor_noise.py",)
METRICS = ("tests/training/test_metrics.py",)
WIENER = ("tests/training/test_wiener.py", "tests/training/test_wiener_numerics.py")
TOLERANCE = ("tests/design/test_tolerance_statistics.py", "tests/design/test_cli_numbers.py",
             "tests/design/test_design_sensitivity.py")
DESIGN_FIT = ("tests/design/test_identifiability.py", "tests/design/test_misalignment.py")
ANALYSIS = ("tests/analysis",)
FAR = ("tests/analysis/test_far_object.py",)
GEOMETRY = ("tests/render/test_geometry.py",)
COMPILED_CALLS = ("tests/optics/test_compiled_calls.py",)
COMPILED = ("tests/optics/test_compiled.py",)
ZMX = ("tests/optics/io/test_zmx.py",)
EVAL_TABLE = ("tests/training/test_eval_table_numbers.py",)
DIFFRACTION = ("tests/render/test_diffraction.py", "tests/render/test_diffraction_oracle.py",
               "tests/render/test_fftconv.py", "tests/render/test_physics.py")
OPTIMIZE_CLI = ("tests/design/test_optimize_steps.py",)
PLOTS = ("tests/analysis/test_plot_output.py",)
RENDER_IMAGE = ("tests/render/test_render_image.py",)
API = ("tests/optics/test_normalized.py", "tests/optics/test_prescription.py")
TRAINING_UX = ("tests/training/test_training_ux.py",)
VSTOP = ("tests/optics/test_virtual_stop.py",)
ELLIPSE = ("tests/optics/io/test_elliptical_apertures.py",)
REFRACT = ("tests/optics/test_refract.py",)
CROSSING = ("tests/optics/test_crossing_azimuths.py",)
PIXEL = ("tests/render/test_diffraction_pixel.py",)
CONFIG = ("tests/training/test_config_errors.py",)
HARDEN_ZMX = ("tests/optics/io/test_zmx_hardening.py",)
FILE_KINDS = ("tests/optics/io/test_file_kinds.py",)
READ_IMAGE = ("tests/render/test_read_image_depth.py",)
ATOMIC = ("tests/training/test_atomic_writes.py",)
LENS2_FTYP3 = ("tests/optics/io/test_zmx_real_image_height.py",)
LENS2_GLASS = ("tests/optics/io/test_zmx_glass_rules.py",)
LENS2_SETUPS = ("tests/optics/io/test_zmx_virtual_object.py",)
RUN_LOCK = ("tests/training/test_run_lock_hydra.py",)
LIMITS = ("tests/optics/test_limits.py",)
INPUT_KEYS = ("tests/training/test_input_keys.py",)
FANOUT_STOP = ("tests/training/test_fanout_stop.py",)
MCONF = ("tests/optics/io/test_zmx_multiconfig.py",)
RAYOPTICS = ("tests/optics/io/test_zmx_corpus_rayoptics.py",)
MCONF_WRITE = ("tests/optics/io/test_zmx_write_configs.py",)
MCONF_OPS = ("tests/optics/io/test_zmx_multiconfig_operands.py",)
TABULATED = ("tests/optics/io/test_tabulated_glass.py",)
JONESMAT = ("tests/optics/io/test_zmx_jonesmat.py",)
ZERN_NOTE = ("tests/optics/io/test_zmx_zernike_paraxial_note.py",)
SURF_SKIP = ("tests/optics/io/test_zmx_surf_numbers.py",)
FLOA_CLAP = ("tests/optics/io/test_zmx_floa_stop_clap.py",)
ZERN_RAYOPTICS = ("tests/optics/io/test_zmx_corpus_rayoptics.py",)
PARAX_XY = ("tests/optics/io/test_zmx_parax_xy.py", "tests/optics/surfaces/test_ideal_xy.py")
IRREGULAR = ("tests/optics/surfaces/test_irregular.py", "tests/optics/io/test_zmx_irregular.py")
SET5_RULES = ("tests/optics/io/test_zmx_set5_rules.py",)
SET6_RULES = ("tests/optics/io/test_zmx_set6_rules.py",)
SET9_RULES = ("tests/optics/io/test_zmx_set9_rules.py",)
BINARY2_RAYOPTICS = ("tests/optics/io/test_zmx_corpus_rayoptics.py",)
GLASS_SEARCH = ("tests/design/search/test_glass_search.py",)
SUBSTITUTION = ("tests/design/search/test_substitution.py",)
CODEV_DECENTER = ("tests/optics/io/test_codev_decenter.py",)
CODEV_DEFAULTS = ("tests/optics/io/test_codev_defaults.py",)
CODEV_CORPUS = ("tests/optics/io/test_codev_corpus.py",)
IRGLASS = ("tests/optics/io/test_infrared_glass.py",)
CODEV_APERTURES = ("tests/optics/io/test_codev_apertures.py",)
CODEV_ZOOM = ("tests/optics/io/test_codev_zoom.py",)
CORNING = ("tests/optics/io/test_corning_glass.py",)
QUARTZ = ("tests/optics/io/test_birefringent_glass.py",)
QBFS_CONIC = ("tests/optics/io/test_zmx_qbfs_conic.py",)
STOP_ON_BREAK = ("tests/optics/io/test_zmx_stop_on_break.py",)
CLAP_BEYOND_DIAM = ("tests/optics/io/test_zmx_clap_beyond_diam.py",)
CAMERA = ("tests/optics/test_camera.py", "tests/render/test_camera_paths.py",
          "tests/training/test_camera_step.py", "tests/training/test_wiener_options.py")


@dataclass(frozen=True)
class Mutation:
    name: str
    what: str  # the bug, in words
    file: str
    old: str
    new: str
    tests: tuple[str, ...]
    issue: bool = False  # named in issue 13 (must be caught)


MUTATIONS = [
    # ------------------------------------------------ rendering (issue 13)
    Mutation("cos4_to_cos2", "relative illumination cos^2 instead of cos^4",
             "deeplens/render/monte_carlo.py", "rays.d[..., 2] ** 4", "rays.d[..., 2] ** 2",
             RENDER, issue=True),
    Mutation("mirror_lr_readout", "image mirrored left-right on the sensor (pixel -> x)",
             "deeplens/render/sensor.py", "return -(j - W / 2) * p, (i - H / 2) * p",
             "return (j - W / 2) * p, (i - H / 2) * p", RENDER, issue=True),
    Mutation("mirror_lr_splat", "forward splats mirrored left-right (x -> pixel)",
             "deeplens/render/sensor.py", "return y / p + H / 2, -x / p + W / 2",
             "return y / p + H / 2, x / p + W / 2", RENDER, issue=True),
    Mutation("mirror_lr_texture", "texture read mirrored left-right",
             "deeplens/render/scene.py", "gx = X / (0.5 * sz[:, 1:2])",
             "gx = -X / (0.5 * sz[:, 1:2])", RENDER, issue=True),
    Mutation("flip_ud_texture", "texture read upside down",
             "deeplens/render/scene.py", "gy = -Y / (0.5 * sz[:, 0:1])",
             "gy = Y / (0.5 * sz[:, 0:1])", RENDER),
    Mutation("no_vignetting_normalisation", "vignetting-on image not normalised by the "
             "on-axis weight", "deeplens/render/monte_carlo.py", "val = num / (S * plan.w_ref[job])",
             "val = num / S", RENDER),
    Mutation("psf_not_flipped", "PSF-convolution renderer correlates instead of convolving",
             "deeplens/render/psf_conv.py", "kers.reshape(-1, 1, K, K).flip(-1, -2)",
             "kers.reshape(-1, 1, K, K)", RENDER),
    # ------------------------------------------------ sensor noise (issue 13)
    Mutation("read_noise_squared", "read noise std given as its variance",
             "deeplens/render/sensor.py", "noise = noise + self.read_noise * torch.randn",
             "noise = noise + self.read_noise ** 2 * torch.randn", NOISE, issue=True),
    Mutation("read_noise_doubled", "read noise twice as strong",
             "deeplens/render/sensor.py", "noise = noise + self.read_noise * torch.randn",
             "noise = noise + 2 * self.read_noise * torch.randn", NOISE, issue=True),
    Mutation("shot_noise_variance_as_std", "shot noise std = I / full_well (no sqrt)",
             "deeplens/render/sensor.py",
             "std = torch.sqrt(image.detach().clamp_min(0) / self.full_well)",
             "std = image.detach().clamp_min(0) / self.full_well", NOISE, issue=True),
    Mutation("shot_noise_sqrt_full_well", "shot noise std = sqrt(I) / full_well",
             "deeplens/render/sensor.py",
             "std = torch.sqrt(image.detach().clamp_min(0) / self.full_well)",
             "std = torch.sqrt(image.detach().clamp_min(0)) / self.full_well", NOISE, issue=True),
    # ------------------------------------------------ metrics (issue 13)
    Mutation("psnr_20log", "PSNR = 20 log10(1 / MSE)", "deeplens/training/metrics.py",
             "return (10 * torch.log10(1.0 / mse)).mean()",
             "return (20 * torch.log10(1.0 / mse)).mean()", METRICS, issue=True),
    Mutation("psnr_of_rmse", "PSNR = 10 log10(1 / RMSE)", "deeplens/training/metrics.py",
             "return (10 * torch.log10(1.0 / mse)).mean()",
             "return (10 * torch.log10(1.0 / mse.sqrt())).mean()", METRICS, issue=True),
    Mutation("psnr_of_batch_mse", "PSNR of the batch-mean MSE instead of the mean PSNR",
             "deeplens/training/metrics.py",
             "return (10 * torch.log10(1.0 / mse)).mean()",
             "return 10 * torch.log10(1.0 / mse.mean())", METRICS, issue=True),
    Mutation("band_radius_half_width", "band radius normalised by half the width, not the "
             "half-diagonal", "deeplens/training/metrics.py",
             "/ (0.5 * (H ** 2 + W ** 2) ** 0.5)", "/ (0.5 * W)", METRICS),
    Mutation("masked_ssim_unmasked", "masked SSIM ignores the mask",
             "deeplens/training/metrics.py", "return smap[:, mask.to(pred.device)].mean()",
             "return smap.mean()", METRICS),
    # ------------------------------------------------ the authors' table reader (issue 13)
    Mutation("table_aspheric_sign", "aspheric coefficients read with the wrong sign",
             "deeplens/optics/io/table.py", "s[\"aspheric\"] = [a * scale",
             "s[\"aspheric\"] = [-a * scale", TABLES, issue=True),
    Mutation("table_conic_sign", "conic constant read with the wrong sign",
             "deeplens/optics/io/table.py", "s[\"conic\"] = extra[0]",
             "s[\"conic\"] = -extra[0]", TABLES),
    Mutation("table_diameter_as_semi", "table diameter taken as the semi-diameter",
             "deeplens/optics/io/table.py", "\"semi_diameter_mm\": diam / 2",
             "\"semi_diameter_mm\": diam", TABLES),
    # ------------------------------------------------ optics (the issue: already caught)
    Mutation("refraction_sign", "vector Snell: + eta cos instead of - eta cos",
             "deeplens/optics/refract.py", "return sign * (one_minus_eta_sq / denom), ok",
             "return sign * sqrt_k + eta * cos_i, ok", OPTICS, issue=True),
    Mutation("refraction_sign_components", "Snell on components (the compiled kernels' layout): "
             "+ coef n_y instead of + coef n_x", "deeplens/optics/refract.py",
             "ex = torch.where(ok, eta * dx + coef * nx, dx)",
             "ex = torch.where(ok, eta * dx + coef * ny, dx)", OPTICS),
    Mutation("sellmeier_sign", "Sellmeier: lambda^2 + C in the denominator",
             "deeplens/optics/materials.py", "n2 = n2 + b * l2 / (l2 - c)",
             "n2 = n2 + b * l2 / (l2 + c)", OPTICS, issue=True),
    Mutation("schott_formula", "SCHOTT power series: a1 lambda^-2 instead of a1 lambda^2",
             "deeplens/optics/materials.py", "n2 = a0 + a1 * l2 + u *", "n2 = a0 + a1 * u + u *",
             OPTICS, issue=True),
    Mutation("zernike_index_off_by_one", "Zernike sag: Noll term j read as term j + 1",
             "deeplens/optics/surfaces/zernike_sag.py",
             "    for j in range(1, n_terms + 1):\n        n, m = nm(j)\n",
             "    for j in range(1, n_terms + 1):\n        n, m = nm(j + 1)\n",
             ("tests/optics/surfaces/test_zernike_sag.py",), issue=True),
    Mutation("fringe_index_off_by_one", "Zernike Fringe sag: Fringe term j read as term j + 1",
             "deeplens/optics/surfaces/zernike_sag.py",
             "    d = math.isqrt(j - 1)\n    pos = j - d * d - 1\n",
             "    d = math.isqrt(j)\n    pos = j - d * d\n",
             ("tests/optics/surfaces/test_zernike_fringe_sag.py",
              "tests/optics/surfaces/test_zernike_sag.py",
              "tests/optics/io/test_zmx_zernike_sag.py")),
    Mutation("asphere_sag_power", "asphere: polynomial one power of r^2 short",
             "deeplens/optics/surfaces/asphere.py", "        p = (p + a.to(s)) * s\n    return p * s\n",
             "        p = (p + a.to(s)) * s\n    return p\n",
             OPTICS, issue=True),
    Mutation("eq7_step_sign", "Eq. 7 differentiable Newton step with the wrong sign",
             "deeplens/optics/intersect.py", "s = s_star - _safe_div(fv, fp, ok)",
             "s = s_star + _safe_div(fv, fp, ok)", OPTICS, issue=True),
    Mutation("opl_without_index", "optical path length without the refractive index",
             "deeplens/optics/lens.py", "opl = rays.opl + n1 * t",
             "opl = rays.opl + t", OPTICS, issue=True),
    Mutation("opl_without_index_quadric", "optical path length without the refractive index in "
             "the closed-form sphere/conic step", "deeplens/optics/intersect.py",
             "n2, ok)\n    return x, y, z + z_shift, ex, ey, ez, ok, opl + n1 * t",
             "n2, ok)\n    return x, y, z + z_shift, ex, ey, ez, ok, opl + t", OPTICS),
    Mutation("pupil_sampling_not_uniform", "random pupil points r = u instead of sqrt(u)",
             "deeplens/optics/sampling.py",
             "r = torch.sqrt(torch.rand(n, generator=g, dtype=torch.float64))",
             "r = torch.rand(n, generator=g, dtype=torch.float64)", OPTICS + RENDER, issue=True),
    Mutation("adjoint_first_chunk_only", "adjoint backward pass visits only the first chunk",
             "deeplens/render/adjoint.py", "for k in range(renderer.n_chunks(plan)):",
             "for k in range(min(1, renderer.n_chunks(plan))):", RENDER, issue=True),
    # ------------------------------------------------ added by issue 25 (numerics)
    Mutation("wiener_correlates", "Wiener filter with H instead of conj H (correlates)",
             "deeplens/training/wiener.py", "G = ch / (h2 + self.nsr()",
             "G = ch.conj() / (h2 + self.nsr()", WIENER),
    Mutation("wiener_nsr_squared", "Wiener filter regularised by nsr^2 instead of nsr",
             "deeplens/training/wiener.py", "self.nsr().to(h2.dtype)[:, None, None])",
             "self.nsr().to(h2.dtype)[:, None, None] ** 2)", WIENER),
    Mutation("wiener_nsr_range_unsquared", "noise-ratio range tiny..max instead of their roots",
             "deeplens/training/wiener.py", "return math.sqrt(fi.tiny), math.sqrt(fi.max)",
             "return fi.tiny, fi.max", WIENER),
    Mutation("tolerance_shared_draw", "Monte Carlo tolerancing: one draw shared by every "
             "parameter", "deeplens/design/tolerance.py",
             "u = 2.0 * torch.rand(len(names), generator=g, dtype=torch.float64) - 1.0",
             "u = (2.0 * torch.rand(1, generator=g, dtype=torch.float64) - 1.0).expand("
             "len(names))", TOLERANCE),
    Mutation("tolerance_halfwidth_as_sigma", "Monte Carlo tolerancing: half-width used as the "
             "standard deviation (draws over +-sqrt(3) t)", "deeplens/design/tolerance.py",
             "x0 + u * t)", "x0 + u * t * 3 ** 0.5)", TOLERANCE),
    Mutation("tolerance_rms_about_mean", "Monte Carlo RMS about the mean instead of about zero",
             "deeplens/design/tolerance.py", '"rms_um": torch.sqrt((s * s).mean(0)).tolist()',
             '"rms_um": torch.sqrt(((s - s.mean(0)) ** 2).mean(0)).tolist()', TOLERANCE),
    Mutation("tolerance_percentile_rank", "Monte Carlo percentiles one decile off",
             "deeplens/design/tolerance.py", "torch.quantile(s, p / 100.0, dim=0)",
             "torch.quantile(s, min(p + 10, 100) / 100.0, dim=0)", TOLERANCE),
    Mutation("rss_sigma_not_squared", "RSS estimate with sigma instead of sigma^2",
             "deeplens/design/sensitivity.py", "c += (J * J).sum(0) * sig ** 2 / W",
             "c += (J * J).sum(0) * sig / W", TOLERANCE),
    Mutation("uncertainty_dof", "fit noise |r|^2 / m instead of / (m - n)",
             "deeplens/design/identifiability.py", "float(r @ r) / max(m - n, 1)",
             "float(r @ r) / m", DESIGN_FIT),
    Mutation("uncertainty_unscaled", "covariance not scaled back from the column-scaled "
             "Jacobian", "deeplens/design/identifiability.py",
             "* sigma ** 2 / torch.outer(norms, norms)", "* sigma ** 2", DESIGN_FIT),
    Mutation("misalignment_centroid_corner", "spot centroid with pixel centres at k, not "
             "k + 1/2", "deeplens/design/misalignment.py",
             "i = torch.arange(H, dtype=img.dtype, device=img.device) + 0.5",
             "i = torch.arange(H, dtype=img.dtype, device=img.device)", DESIGN_FIT),
    Mutation("dls_predicted_reduction_sign", "damped least squares: predicted reduction with "
             "the step's sign flipped", "deeplens/design/optimizers.py",
             "pred = F - float(((r + J @ delta) ** 2).sum())",
             "pred = F - float(((r - J @ delta) ** 2).sum())",
             ("tests/design/test_design_optimizers.py",)),
    Mutation("wavefront_opd_sign", "OPD sign flipped (late rays positive)",
             "deeplens/analysis/wavefront.py",
             "opd = (ref - (tr.opl - tr.n_image * s)) / (wl * 1e-6)",
             "opd = ((tr.opl - tr.n_image * s) - ref) / (wl * 1e-6)", ANALYSIS),
    Mutation("zernike_normalisation", "standard Zernike terms without the 1/(1 + delta_m0) of "
             "their normalisation", "deeplens/analysis/wavefront.py",
             "z = z * math.sqrt(2 * (n + 1) / (1 + (m == 0)))", "z = z * math.sqrt(2 * (n + 1))",
             ANALYSIS),
    Mutation("far_object_launch_direction", "far-object launch point moved the wrong way along "
             "the ray", "deeplens/optics/sampling.py",
             "o = torch.cat([P[:, :2] + (z_start - P[:, 2:]) * t,",
             "o = torch.cat([P[:, :2] + (P[:, 2:] - z_start) * t,", FAR),
    Mutation("launch_path_difference", "wavefront launch: path difference with t - t0 for "
             "t + t0", "deeplens/analysis/wavefront.py", "(xy64 * (t + t0)).sum(-1)",
             "(xy64 * (t - t0)).sum(-1)", FAR),
    Mutation("image_circle_probe_margin", "image-circle probe aims only over the enlarged "
             "pupil (large pupil_margin: black image)", "deeplens/render/geometry.py",
             "radius[n_p // 2:] = float(r_core)", "radius[n_p // 2:] = float(r_xp)", GEOMETRY),
    Mutation("reference_weight_strata_unweighted", "reference weight: strata averaged without "
             "their area shares", "deeplens/render/geometry.py",
             "val += share * float(", "val += 0.5 * float(", GEOMETRY),
    Mutation("stop_between_media_accepted", "an aperture stop between two media accepted",
             "deeplens/optics/lens.py",
             "if s.interaction.same_medium:  # a stop does not refract",
             "if False:  # a stop does not refract", ("tests/optics/test_stop_media.py",)),
    Mutation("compiled_donated_buffers", "compiled kernels keep buffer donation (a second "
             "backward raises)", "deeplens/optics/compiled.py",
             "torch._functorch.config.donated_buffer = False", "pass", COMPILED_CALLS),
    Mutation("compiled_silent_fallback", "beyond the recompile limit the compiler falls back "
             "silently", "deeplens/optics/compiled.py", "fail_on_recompile_limit_hit=True",
             "fail_on_recompile_limit_hit=False", COMPILED_CALLS),
    Mutation("compiled_run_media_swapped", "fused surface run: media indices before/after "
             "swapped", "deeplens/optics/tracer.py",
             "params.append(((pivot + vertex)[2], *values, _compact(n1).to(like),\n"
             "                           _compact(n2).to(like)))",
             "params.append(((pivot + vertex)[2], *values, _compact(n2).to(like),\n"
             "                           _compact(n1).to(like)))", COMPILED),
    Mutation("compiled_newton_opl", "compiled Newton kernel: optical path without the index",
             "deeplens/optics/compiled.py", "ok, opl + n1 * t)", "ok, opl + t)", COMPILED),
    Mutation("zmx_diam_as_diameter", "Zemax DIAM read as a full diameter",
             "deeplens/optics/io/zmx_parse.py",
             'cur.diam, cur.diam_line = p.arg(toks, 1, ln, "semi-diameter"), ln',
             'cur.diam, cur.diam_line = 0.5 * p.arg(toks, 1, ln, "semi-diameter"), ln', ZMX),
    Mutation("zmx_conic_sign", "Zemax CONI read with the wrong sign",
             "deeplens/optics/io/zmx_parse.py",
             'cur.coni = p.arg(toks, 1, ln, "conic constant")',
             'cur.coni = -p.arg(toks, 1, ln, "conic constant")', ZMX),
    Mutation("eval_std_population", "eval table: seed spread with n instead of n - 1",
             "deeplens/evaluation/evaluate.py", "sum((v - m) ** 2 for v in values) / (n - 1))",
             "sum((v - m) ** 2 for v in values) / n)", EVAL_TABLE),
    Mutation("eval_ssim_under_psnr", "eval table: the SSIM column shows the sensor image's",
             "deeplens/evaluation/evaluate.py",
             'entry[img] = {f"{d:g}": cell(f"test/psnr_{img}/d{d:g}mm", f"test/ssim_{img}/d{d:g}mm")',
             'entry[img] = {f"{d:g}": cell(f"test/psnr_{img}/d{d:g}mm", f"test/ssim_sensor/d{d:g}mm")',
             EVAL_TABLE),
    Mutation("checkpoint_digest_unchecked", "checkpoint digest never verified on read",
             "deeplens/training/checkpoint.py", "        if digest not in listed:",
             "        if False:", ("tests/training/test_checkpoint_io.py",)),
    # ------------------------------------------------ diffraction PSF (issue 19)
    Mutation("diffraction_no_pixel_integration", "diffraction kernel: every sub-pixel point at "
             "the pixel centre (point samples, no pixel integration)",
             "deeplens/render/diffraction.py", "return (0.5 * x).tolist(), (0.5 * w).tolist()",
             "return (0.0 * x).tolist(), (0.5 * w).tolist()", DIFFRACTION),
    Mutation("diffraction_near_centre_at_infinity", "diffraction kernel: a near object's "
             "reference sphere centred on the image of infinity (same direction)",
             "deeplens/render/diffraction.py", "cx, cy = _ideal_xy(camera, X, Y, depth)",
             "cx, cy = (_ideal_xy(camera, X / depth, Y / depth, math.inf) if math.isfinite("
             "depth) else _ideal_xy(camera, X, Y, depth))", DIFFRACTION),
    Mutation("diffraction_near_plane_wave", "diffraction kernel: a near object launched as a "
             "plane wave (no path from the object point to the start plane)",
             "deeplens/render/diffraction.py", "L = n0 * (t - (zs - float(P[2])))",
             "L = n0 * 0 * t", DIFFRACTION),
    Mutation("diffraction_flip_x", "diffraction kernel mirrored left-right (columns along +x)",
             "deeplens/render/diffraction.py", "xj = -t * pitch", "xj = t * pitch", DIFFRACTION),
    Mutation("diffraction_flip_y", "diffraction kernel upside down (rows along -y)",
             "deeplens/render/diffraction.py", "yi = t * pitch           # rows: +y",
             "yi = -t * pitch          # rows: +y", DIFFRACTION),
    Mutation("diffraction_shift_one_pixel", "diffraction kernel shifted by one pixel",
             "deeplens/render/diffraction.py", "- K // 2 + x[None, :]",
             "- K // 2 + 1 + x[None, :]", DIFFRACTION),
    Mutation("diffraction_fixed_wavelength_phase", "diffraction pupil phase at a fixed 587.6 "
             "nm for every job (wavelength scaling of the OPD)",
             "deeplens/render/diffraction.py", "lam = wl * 1e-6", "lam = 587.5618e-6",
             DIFFRACTION),
    Mutation("diffraction_fixed_wavelength_transform", "diffraction transform scaled at a "
             "fixed 587.6 nm (wavelength scaling of the PSF's size)",
             "deeplens/render/diffraction.py",
             "bx, by, n_img, lam = as_t(bx), as_t(by), as_t(n_img), as_t(lam)",
             "bx, by, n_img, lam = as_t(bx), as_t(by), as_t(n_img), as_t(587.5618e-6)",
             DIFFRACTION),
    Mutation("diffraction_fit_cache_ignores_mask", "OPD fit's least-squares map cached without "
             "its vignetting mask", "deeplens/render/diffraction.py",
             'key = ("fit", n, degree, str(m.device), sel.cpu().numpy().tobytes())',
             'key = ("fit", n, degree, str(m.device))',
             DIFFRACTION),
    Mutation("fftconv_no_flip", "FFT convolution correlates with the flipped kernel",
             "deeplens/render/fftconv.py", "Kf = torch.fft.rfft2(k.flip(-1, -2)[:, 0]",
             "Kf = torch.fft.rfft2(k[:, 0]", DIFFRACTION),
    # issue 23 part B (CLI, API, plots, training UX)
    Mutation("quick_focus_sign", "quick focus moves the sensor the wrong way",
             "deeplens/design/focus.py", "t = -num / den", "t = num / den", OPTIMIZE_CLI),
    Mutation("vignetting_count_off", "the rejection reason miscounts the vignetted rays",
             "deeplens/design/merit.py", 'raise Infeasible(f"{int(lost.sum())} of',
             'raise Infeasible(f"{int(lost.sum()) + 1} of', OPTIMIZE_CLI),
    Mutation("allow_vignetting_ignored", "optimize --allow-vignetting has no effect",
             "deeplens/cli.py", "strict_rays=not args.allow_vignetting", "strict_rays=True",
             OPTIMIZE_CLI),
    Mutation("vector_as_png", "-o x.pdf writes PNG bytes", "deeplens/analysis/style.py",
             "fig.savefig(buf, format=fmt, dpi=dpi", 'fig.savefig(buf, format="png", dpi=dpi',
             PLOTS),
    Mutation("poly_mtf_no_lateral_colour", "polychromatic MTF ignores where each wavelength "
             "images", "deeplens/analysis/mtf_poly.py",
             'return {"tangential": (p.psf.sum(1), p.y + p.center[1]),',
             'return {"tangential": (p.psf.sum(1), p.y),', PLOTS),
    Mutation("spot_rms_paraxial_pupil", "spot figure RMS over the paraxial pupil (differs "
             "from report)", "deeplens/analysis/plot.py",
             'image_plane="sensor", pupil: str = "traced", options=None):',
             'image_plane="sensor", pupil: str = "paraxial", options=None):', PLOTS),
    Mutation("render_upside_down", "deeplens render flips the picture",
             "deeplens/render/image.py", "scene = Scene(image.to(lens.dtype), float(depth_mm))",
             "scene = Scene(image.flip(-2).to(lens.dtype), float(depth_mm))", RENDER_IMAGE),
    Mutation("render_no_srgb_encode", "deeplens render writes linear values as sRGB",
             "deeplens/render/image.py", "v = v if linear else linear_to_srgb(v)", "v = v",
             RENDER_IMAGE),
    Mutation("radius_is_curvature", "Surface.radius returns c, not 1/c",
             "deeplens/optics/surfaces/base.py", "return math.inf if c == 0.0 else 1.0 / c",
             "return math.inf if c == 0.0 else c", API),
    Mutation("pupil_xy_swapped", "normalised pupil coordinates (Px, Py) swapped",
             "deeplens/optics/normalized.py", "u = newton(u, P * r_stop, iterations)",
             "u = newton(u, P.flip(-1) * r_stop, iterations)", API),
    Mutation("field_sin_not_tan", "normalised field direction from sin instead of tan",
             "deeplens/optics/normalized.py", "tan = torch.tan(torch.deg2rad(H * theta_max))",
             "tan = torch.sin(torch.deg2rad(H * theta_max))", API),
    Mutation("psf_panels_own_scale", "TensorBoard PSF panels each normalised to their own peak",
             "deeplens/training/psf_panels.py", "im = ax.imshow((k / vmax).numpy()",
             "im = ax.imshow((k / max(float(k.max()), 1e-12)).numpy()", TRAINING_UX),
    Mutation("broken_pipe_traceback", "report piped into a reader that stops early: a "
             "BrokenPipeError traceback", "deeplens/cli.py", "    except BrokenPipeError:",
             "    except ZeroDivisionError:", ("tests/test_cli.py",)),
    # ------------------------------------------------ a stop inside a lens's sag (issue 22)
    Mutation("virtual_stop_lands", "the stop moves the rays onto its plane (backwards when the "
             "next surface lies before it)", "deeplens/optics/lens.py",
             "        if virtual:\n", "        if False:\n", VSTOP),
    Mutation("virtual_stop_t_sign", "the stop's crossing computed with the wrong sign of t",
             "deeplens/optics/intersect.py", "t = _safe_div(-oz, dz, ok)   # of either sign",
             "t = _safe_div(oz, dz, ok)   # of either sign", VSTOP),
    Mutation("virtual_stop_ahead_only", "the stop accepts crossings ahead of the ray only "
             "(t >= 0, as a landed hit): a stop behind the ray blocks it",
             "deeplens/optics/intersect.py",
             "ok = ok & torch.isfinite(X) & torch.isfinite(Y)\n",
             "ok = ok & torch.isfinite(X) & torch.isfinite(Y) & (t >= 0)\n", VSTOP),
    # ------------------------------------------------ the camera (issue 24)
    Mutation("camera_trace_default_options", "Camera.trace_to_sensor traces at the default "
             "options, not the camera's", "deeplens/optics/camera.py",
             "z_image=z_image, options=self.options)", "z_image=z_image, options=None)", CAMERA),
    Mutation("camera_unpack_drops_options", "a function given a camera traces at the default "
             "options (PSFs, spot diagram)", "deeplens/optics/camera.py",
             "return cam.lens, cam.sensor, cam.options", "return cam.lens, cam.sensor, None",
             CAMERA),
    Mutation("wiener_default_options", "the Wiener filter's PSFs trace at the default options, "
             "not the camera's", "deeplens/training/wiener.py",
             "lens, sensor, options = cam.lens, cam.sensor, cam.options",
             "lens, sensor, options = cam.lens, cam.sensor, None", CAMERA),
    Mutation("renderer_options_copied", "the Monte Carlo renderer keeps the options it was built "
             "with (a copy), so options set on the camera later never reach it",
             "deeplens/render/monte_carlo.py",
             "        self.pupil_margin = float(pupil_margin)\n",
             "        self.pupil_margin = float(pupil_margin)\n"
             "        self._frozen = camera.options\n"
             "        type(self).options = property(lambda s: s._frozen)\n", CAMERA),
    # ------------------------------------------------ the centring compensator (issue 21)
    Mutation("center_sign_flip", "the centring compensator moves the lens the wrong way (+ miss)",
             "deeplens/optics/tolerance_model.py",
             "values.get(name, params[name]) - miss[k].to(params[name])",
             "values.get(name, params[name]) + miss[k].to(params[name])",
             ("tests/design/test_tolerance_model.py",)),
    Mutation("center_ignored", "compensator: center parsed but never applied",
             "deeplens/optics/tolerance_model.py", "        if draw.center:\n",
             "        if False and draw.center:\n", ("tests/design/test_tolerance_model.py",)),
    Mutation("adjoint_grad_through_originals", "the adjoint pass differentiates the lens's "
             "tensors as they are, not re-entered as leaves (counts a compensator's path twice)",
             "deeplens/render/adjoint.py",
             "leaves = {n: current[n].detach().requires_grad_(True) for n in names}",
             "leaves = {n: current[n] for n in names}", ("tests/design/test_tolerance_model.py",)),
    Mutation("lens_fixed_not_restored", "the optics stay frozen after camera.lens_fixed() (warm-up "
             "never ends)", "deeplens/optics/camera.py",
             "            for p in params:\n                p.requires_grad_(True)",
             "            for p in params:\n                pass", CAMERA),
    # ------------------------------------------------ one config check at start-up (issue 24)
    Mutation("startup_skips_model_check", "check_config no longer calls the model's validator "
             "(model.* refused only when the module is built, after the lens and the data)",
             "deeplens/training/train.py", "_check_render, check_model_config,",
             "_check_render,", CONFIG),
    Mutation("soft_max_bins_unchecked", "model.worst_depth.bins no longer checked",
             "deeplens/training/settings.py",
             "    if not (isinstance(K, int) and not isinstance(K, bool) and K >= 1):\n",
             "    if False:\n", CONFIG),
    # ------------------------------------------------ hardening, round three (issue 38)
    Mutation("zmx_second_stop_wins", "a .zmx with two STOP lines read silently (the last wins)",
             "deeplens/optics/io/zmx_parse.py", "    if st.stop_at is not None:",
             "    if False:", HARDEN_ZMX),
    Mutation("zmx_lengths_unchecked", "a .zmx DISZ/DIAM/ENPD of 1e308 read (overflowed paraxial "
             "data)", "deeplens/optics/io/zmx_parse.py",
             "if math.isfinite(v) and abs(v) * s_mm > MAX_LENGTH_MM:", "if False:", HARDEN_ZMX),
    Mutation("zmx_length_limit_in_file_units", "the .zmx length limit applied in the file's unit, "
             "not mm", "deeplens/optics/io/zmx_parse.py",
             "if math.isfinite(v) and abs(v) * s_mm > MAX_LENGTH_MM:",
             "if math.isfinite(v) and abs(v) > MAX_LENGTH_MM:", HARDEN_ZMX),
    Mutation("json_curvature_unlimited", "a JSON curvature of 1e308 per mm accepted (an "
             "OverflowError traceback)", "deeplens/optics/io/lensfile.py",
             "                if abs(v) > MAX_CURVATURE_PER_MM:", "                if False:",
             HARDEN_ZMX),
    Mutation("agf_nan_index_accepted", "an .agf glass with n^2 < 0 or n < 1 at the design "
             "wavelengths accepted (a report of nan)", "deeplens/optics/io/zmx_read.py",
             "        _check_index(mat, waves_nm, s, surfs.index(s), p)\n", "", HARDEN_ZMX),
    Mutation("agf_formula_inf_traceback", "an .agf formula number inf: an OverflowError "
             "traceback", "deeplens/optics/io/agf.py",
             "if not math.isfinite(formula) or formula != int(formula)",
             "if formula != int(formula)", HARDEN_ZMX),
    Mutation("utf16_without_mark_undetected", "a UTF-16 .zmx without byte-order mark decoded "
             "as UTF-8 (NUL bytes, nothing read)", "deeplens/optics/io/agf.py",
             "    if utf16 is not None:", "    if False:", HARDEN_ZMX),
    Mutation("lens_file_any_kind", "lens/glass readers open any path (a FIFO blocks, "
             "/dev/zero is read)", "deeplens/optics/io/filecheck.py",
             "    if not stat.S_ISREG(st.st_mode):", "    if False:", FILE_KINDS),
    Mutation("lens_file_unbounded", "lens/glass files read whatever their size",
             "deeplens/optics/io/filecheck.py", "    if st.st_size > MAX_FILE_BYTES:",
             "    if False:", FILE_KINDS),
    Mutation("render_16bit_through_8bit", "deeplens render reads 16-bit greyscale through an "
             "8-bit conversion (clips)", "deeplens/render/image.py",
             "            if im.mode in _HIGH_DEPTH:", "            if False:", READ_IMAGE),
    Mutation("render_16bit_scaled_by_255", "16-bit greyscale scaled by 255",
             "deeplens/render/image.py", "    else:\n        scale = 65535.0\n",
             "    else:\n        scale = 255.0\n", READ_IMAGE),
    Mutation("render_bomb_traceback", "a 20000 x 20000 PNG header: a DecompressionBombError "
             "traceback", "deeplens/render/image.py",
             "    except Image.DecompressionBombError as e:", "    except ZeroDivisionError as e:",
             READ_IMAGE),
    Mutation("zmx_cut_off_silent", "a .zmx cut after a lens surface read silently as a shorter "
             "lens", "deeplens/optics/io/zmx_parse.py",
             "    if last.disz_line and last.disz == 0:\n        return\n",
             "    return\n", HARDEN_ZMX),
    Mutation("garbage_digest_loads", "a garbage .sha256 lets a damaged checkpoint load "
             "unverified (a warning only)", "deeplens/training/checkpoint.py",
             "    if side.exists() and not listed:\n", "    if False:\n",
             ("tests/training/test_faults.py",)),
    Mutation("perceptual_pickle_traceback", "a pickle as model.perceptual_weights refused with "
             "torch's raw UnpicklingError", "deeplens/nets/losses.py",
             "        except Exception as e:  # noqa: BLE001 - torch raises many kinds",
             "        except ZeroDivisionError as e:  # noqa: BLE001 - torch raises many kinds",
             ("tests/nets/test_perceptual_weights_file.py",)),
    Mutation("atomic_mode_0600", "atomically written files keep mkstemp's mode 0600",
             "deeplens/optics/io/atomic.py", "    os.chmod(tmp, mode)\n", "", ATOMIC),
    Mutation("stale_temps_kept", "temporary files of a killed write never cleaned up",
             "deeplens/optics/io/atomic.py", "    clean_stale_temps(path)\n    fd, tmp",
             "    fd, tmp", ATOMIC),
    Mutation("stale_cleanup_any_tmp", "the clean-up removes every *.tmp in the folder",
             "deeplens/optics/io/atomic.py",
             'pattern = re.compile(re.escape(path.name) + r"\\." + _RANDOM + r"\\.tmp")',
             'pattern = re.compile(r".*\\.tmp")', ATOMIC),
    Mutation("stale_cleanup_live_files", "the clean-up removes a live writer's fresh temporary "
             "file", "deeplens/optics/io/atomic.py", "now - st.st_mtime > older_than_s",
             "True", ATOMIC),
    Mutation("efbig_as_disk_full", "a write stopped by a file-size limit (ulimit -f, FAT32) "
             "reported as a full disk", "deeplens/training/checkpoint.py",
             "            why = (_file_too_large(e, path.parent, written) or _disk_full(",
             "            why = (None or _disk_full(", ("tests/training/test_faults.py",)),
    Mutation("checkpoint_structure_unchecked", "a checkpoint that passes its digest but holds a "
             "list where a dict belongs: a raw KeyError/AttributeError later",
             "deeplens/training/checkpoint.py", "    check_structure(ckpt, path, resume=resume)\n",
             "", ("tests/training/test_faults.py",)),
    Mutation("resume_from_weights_only", "a weights-only checkpoint accepted for resuming",
             "deeplens/training/checkpoint.py", "    if resume:\n        missing",
             "    if False:\n        missing", ("tests/training/test_faults.py",)),
    Mutation("old_checkpoint_not_migrated", "a previous version's checkpoint (no obscuration/"
             "decenter buffers) refused as another experiment", "deeplens/training/checkpoint.py",
             '    migrate_missing_buffers(checkpoint["state_dict"], module, path)\n', "",
             ("tests/training/test_checkpoint_migration.py",)),
    Mutation("migration_overrides_values", "migration fills missing buffers whatever this "
             "model's value (a non-default obscuration silently reset)",
             "deeplens/training/checkpoint.py",
             "        if torch.equal(v.detach().cpu().double(), torch.tensor(default, "
             "dtype=torch.float64)):", "        if True:",
             ("tests/training/test_checkpoint_migration.py",)),
    Mutation("fanout_folder_unquoted", "the fan-out passes its folder to Hydra unquoted "
             "(E2 (copy), E2,v2 fail)", "deeplens/evaluation/fanout.py",
             'f"eval.folder={hydra_quote(out)}"', 'f"eval.folder={out}"',
             ("tests/training/test_fanout_quoting.py",)),
    Mutation("hydra_quote_no_escapes", "quoted values without escaping quotes and ${",
             "deeplens/evaluation/fanout.py",
             """    v = v.replace("'", "\\\\'").replace("${", "\\\\${")""", "    v = v",
             ("tests/training/test_fanout_quoting.py",)),
    Mutation("lock_after_hydra_writes", "deeplens train takes the folder lock in the task, after "
             "Hydra rewrote the live run's .hydra files", "configs/train.yaml",
             "    output_folder_lock:\n      _target_: deeplens.training.run_lock.OutputFolderLock\n",
             "", RUN_LOCK),
    Mutation("lock_refusal_swallowed", "the callback's refusal raised as an exception (Hydra "
             "turns it into a warning and runs the job)", "deeplens/training/run_lock.py",
             "            raise RunRefused(e) from None", "            raise", RUN_LOCK),
    Mutation("task_locks_twice", "the task locks the folder the callback holds (a run refuses "
             "itself)", "deeplens/training/train.py",
             "held = child or held_by_hydra(cfg.paths.output_dir)", "held = child", RUN_LOCK),
    # issue 37 (lens files users have), second round
    Mutation("ftyp3_no_step_back", "FTYP 3 solve gives up at a trial angle whose chief ray "
             "fails instead of stepping back", "deeplens/optics/io/zmx_system.py",
             "bad, t = t, 0.5 * (lo + t)", "bad, t = t, t", LENS2_FTYP3),
    Mutation("model_glass_preferred", "a named catalogue glass silently replaced by the model "
             "glass of the GLAS line's (stale) n_d/V_d", "deeplens/optics/io/zmx_parse.py",
             'if name.upper() == "___BLANK" or code == "1":',
             'if name.upper() == "___BLANK" or code == "1" or model is not None:', LENS2_GLASS),
    Mutation("zernike_vertex_note_dropped", "a Zernike sag whose m = 0 terms curve the vertex "
             "read without the note that the paraxial data include them",
             "deeplens/optics/io/surface_handlers.py", "        if dc != 0.0:\n            p.note_each(",
             "        if dc != 0.0:\n            (lambda *a: None)(", ZERN_NOTE),
    Mutation("jonesmat_silent", "a JONESMAT surface read as a plane without the note that its "
             "matrix is not applied", "deeplens/optics/io/surface_handlers.py",
             "        ctx.p.note_each(s.type_line, _JONES,",
             "        (lambda *a: None)(s.type_line, _JONES,", JONESMAT),
    Mutation("jonesmat_curved_accepted", "a curved JONESMAT read as a plane",
             "deeplens/optics/io/surface_handlers.py",
             "        if s.curv != 0:\n            p.fail(s.curv_line or s.type_line, f\"SURF {k}: a "
             "JONESMAT", "        if False:\n            p.fail(s.curv_line or s.type_line, "
             "f\"SURF {k}: a JONESMAT", JONESMAT),
    Mutation("tabulated_glass_silent", "an LZOS glass fitted to its index table used without "
             "the located note naming the source", "deeplens/optics/io/zmx_glass.py",
             "                p.note_each(s.glass_line,\n                            Cause(one=",
             "                (lambda *a: None)(s.glass_line,\n                            Cause(one=",
             TABULATED),
    Mutation("tabulated_glass_fit_in_n", "the Schott formula fitted to n instead of n²",
             "deeplens/optics/io/tabulated_glass.py",
             "np.asarray(n, dtype=np.float64) ** 2, rcond=None)",
             "np.asarray(n, dtype=np.float64), rcond=None)", TABULATED),
    Mutation("glass_fallback_silent", "the model-glass fallback used without its warning",
             "deeplens/optics/io/zmx_glass.py",
             "        p.note_each(s.glass_line, cause, repr(glass), detail)\n        return m",
             "        return m", LENS2_GLASS),
    Mutation("virtual_object_launched_behind", "rays of a virtual object started on its plane "
             "(behind the lens) instead of before the first surface",
             "deeplens/optics/sampling.py",
             "z0 = float(z_start) if virtual else max(float(z_start), z_obj)",
             "z0 = max(float(z_start), z_obj)", LENS2_SETUPS),
    Mutation("virtual_object_wavefront_clamped", "the wavefront launch of a virtual object "
             "started on the object plane (behind the lens)", "deeplens/analysis/wavefront.py",
             "if float(z_obj) <= float(lens.z_vertices()[0]):", "if True:", LENS2_SETUPS),
    Mutation("sqap_ignored_off_asphere", "a rectangular clear aperture (SQAP) on a surface "
             "other than an even asphere read but not clipped", "deeplens/optics/surfaces/base.py",
             'rect = self._buffers.get("clear_rect")',
             "rect = None", ("tests/optics/io/test_zmx_sqap_any_surface.py",)),
    Mutation("xasphere_rn_power", "Extended Asphere term i divided by R_n^i instead of "
             "R_n^(2i)", "deeplens/optics/io/surface_handlers.py",
             "ai = v * s_mm / rn ** (2 * i)", "ai = v * s_mm / rn ** i",
             ("tests/optics/io/test_zmx_xasphere.py",)),
    Mutation("sqap_sag_surfaces_only", "a rectangular clear aperture refused on an implicit "
             "surface (a TILTSURF's XYPolynomial) although it is tested at the hit's x, y",
             "deeplens/optics/surfaces/base.py",
             "    return issubclass(cls, Surface) and bool(cls.interaction.lands)",
             "    return issubclass(cls, SagSurface) and bool(cls.interaction.lands)",
             ("tests/optics/io/test_zmx_sqap_tilted.py",)),
    Mutation("crossing_outside_openings", "surfaces checked for crossing over their whole "
             "circumscribed circle, outside a rectangular opening (a cube's diagonal refused)",
             "deeplens/optics/lens.py",
             "& a.opening.outer.contains(x, y) & b.opening.outer.contains(x, y))", ")",
             ("tests/optics/io/test_zmx_sqap_tilted.py",)),
    Mutation("long_wave_medium_range_ignored", "the > 100 µm unit guard applied although the "
             "medium's range covers the wavelength (a constant index at 3 mm refused)",
             "deeplens/optics/materials.py", "    if hi > 1e5 and not (stated_unit or covered):",
             "    if hi > 1e5 and not stated_unit:", ("tests/optics/io/test_zmx_long_waves.py",)),
    Mutation("zmx_wavm_unit_not_stated", "a .zmx lens's wavelengths treated as bare numbers "
             "(the WAVM µm unit forgotten: a millimetre-wave file refused)",
             "deeplens/optics/io/zmx_read.py",
             "primary_wavelength_nm=primary, wavelength_unit_stated=True)",
             "primary_wavelength_nm=primary)", ("tests/optics/io/test_zmx_long_waves.py",)),
    Mutation("object_at_zero_refused_before_gap", "an object at DISZ 0 refused although dummy "
             "gaps put it before the first traced surface", "deeplens/optics/io/zmx_read.py",
             "    if not (obj_dist >= 0 or math.isfinite(obj_dist)):",
             "    if not (obj_dist > 0 or (obj_dist < 0 and math.isfinite(obj_dist))):",
             ("tests/optics/io/test_zmx_object_at_zero.py",)),
    # ------------------------------------------------ hardening, round three, part 2 (issue 38)
    Mutation("budget_ignores_rlimit", "the memory budget ignores the process's address-space "
             "limit (ulimit -v): an allocator error instead of the setting",
             "deeplens/optics/limits.py",
             "for x in (_physical(), _address_space(), _cgroup())",
             "for x in (_physical(), _cgroup())", LIMITS),
    Mutation("budget_ignores_cgroup", "the memory budget ignores the cgroup's memory limit "
             "(Slurm --mem): the OOM killer instead of the setting", "deeplens/optics/limits.py",
             "for x in (_physical(), _address_space(), _cgroup())",
             "for x in (_physical(), _address_space())", LIMITS),
    Mutation("cgroup_leaf_only", "only the process's own cgroup read, not its ancestors (a "
             "Slurm job's limit set on job_N, the task in job_N/step_0)",
             "deeplens/optics/limits.py", "                if d == base or base not in d.parents:",
             "                if True:", LIMITS),
    Mutation("rlimit_ignores_mapped", "the address-space budget counts the whole limit, not what "
             "is left of it (torch's libraries already map gigabytes)",
             "deeplens/optics/limits.py", "    return (max(soft - used, 0),",
             "    return (soft,", LIMITS),
    Mutation("classical_key_on_path", "the classical design keyed on the lens path (an edited "
             "lens reuses the old design and its run)", "deeplens/evaluation/classical.py",
             '    key["inputs"] = input_digests(key, outputs=[out_dir])\n', "", INPUT_KEYS),
    Mutation("zmx_catalogues_not_digested", "a .zmx lens's run key without the .agf catalogues "
             "its GCAT line loads (an edited glass reuses the old runs)",
             "deeplens/training/input_digest.py",
             "            out.update(zmx_catalogue_digests(tree, _catalogs, prefix))\n",
             "            pass\n", INPUT_KEYS),
    Mutation("zmx_options_catalogues_ignored", "the key digests the .agf next to the .zmx although "
             "lens.table_options.glass_catalogs answers for its name",
             "deeplens/training/input_digest.py",
             '            cats = _glass_catalogs(tree) if k == "path" else ()',
             "            cats = ()", INPUT_KEYS),
    Mutation("catalogue_files_ignore_passed", "catalogue_files lists the .agf next to the lens "
             "for a name a passed catalogue answers", "deeplens/optics/io/zmx_glass.py",
             "            names.add(Path(c).stem.upper())\n", "", INPUT_KEYS),
    Mutation("fanout_signal_not_forwarded", "SIGTERM/Ctrl-C to a fanned-out eval not passed on "
             "to its jobs (they train on until the grace's SIGKILL)",
             "deeplens/evaluation/fanout_stop.py",
             "            _signal_group(pgid, signal.SIGTERM)\n", "            pass\n", FANOUT_STOP),
    Mutation("fanout_no_process_group", "the multirun started in the evaluation's own process "
             "group (the group signals reach nothing; the jobs go on training)",
             "deeplens/evaluation/fanout_stop.py", "start_new_session=True,",
             "start_new_session=False,", FANOUT_STOP),
    Mutation("fanout_no_pdeathsig", "the multirun not told to die with the evaluation (kill -9 "
             "leaves it running)", "deeplens/evaluation/fanout_stop.py",
             "    return lambda: prctl(1, signal.SIGTERM, 0, 0, 0)",
             "    return None", FANOUT_STOP),
    Mutation("job_watchdog_off", "a job's watchdog never stops it (kill -9 of the evaluation: "
             "the jobs go on writing)", "deeplens/evaluation/fanout_stop.py",
             "        while parent_alive(token):", "        while True:", FANOUT_STOP),
    Mutation("job_watchdog_not_started", "a fanned-out job does not start its watchdog",
             "deeplens/evaluation/evaluate.py", "        watch_parent()   # stop",
             "        pass   # stop", FANOUT_STOP),
    Mutation("watchdog_zombie_alive", "a killed evaluation not yet reaped (a zombie) counts as "
             "alive", "deeplens/evaluation/fanout_stop.py",
             'if not fields or fields[0] in ("Z", "X"):', 'if not fields or fields[0] in ("X",):',
             FANOUT_STOP),
    # ------------------------------------------------ multi-configuration .zmx (issue 37 item 6)
    Mutation("mconf_thic_ignored", "a configuration's THIC row not applied (every configuration "
             "reads the saved gaps)", "deeplens/optics/io/zmx_mconf.py",
             "            s.disz, s.disz_line = _repeat(s.disz, v), ln",
             "            s.disz_line = ln", MCONF),
    Mutation("mconf_unsupported_silent", "an unsupported operand that changes the lens ignored",
             "deeplens/optics/io/zmx_mconf.py", "            if not same:\n",
             "            if False:\n", MCONF),
    Mutation("mconf_field_off_by_one", "YFIE f sets field f - 1", "deeplens/optics/io/zmx_mconf.py",
             "        vals[num - 1] = _repeat(vals[num - 1], v)\n        sysd[slot]",
             "        vals[num - 2] = _repeat(vals[num - 2], v)\n        sysd[slot]",
             MCONF),
    Mutation("mconf_object_1e10_finite", "THIC 0 of 1e10 read as a finite object distance",
             "deeplens/optics/io/zmx_mconf.py", "if num == 0 and v >= OBJECT_AT_INFINITY:", "if False:",
             MCONF),
    Mutation("mconf_not_shared", "read_zmx_configs shares no surface (copies)",
             "deeplens/optics/io/zmx_configs.py", "            L.surfaces[i] = s", "            pass",
             MCONF),
    Mutation("mconf_shared_size_first", "a shared surface keeps configuration 1's automatic "
             "semi-diameter, not the largest", "deeplens/optics/io/zmx_configs.py",
             "s.semi_diameter.fill_(max(sizes))", "s.semi_diameter.fill_(sizes[0])", MCONF),
    # ------------------------------------------------ issue 38: numerical defects
    Mutation("snell_k_cancels", "Snell's k evaluated as 1 - eta^2 (1 - cos^2): equal indices "
             "lose grazing rays in float32", "deeplens/optics/refract.py",
             "    k = one_minus_eta_sq + eta_sq_c2\n",
             "    k = 1.0 - (eta * eta) * (1.0 - cos_i * cos_i)\n", REFRACT),
    Mutation("snell_coef_cancels", "Snell's coefficient as sqrt(k) - eta cos (cancels for "
             "nearly equal indices)", "deeplens/optics/refract.py",
             "    return sign * (one_minus_eta_sq / denom), ok\n",
             "    return sign * sqrt_k - eta * cos_i, ok\n", REFRACT),
    Mutation("check_along_y_only", "Lens.check looks for crossing surfaces along y only (a "
             "biconic crossing its neighbour along x is accepted)", "deeplens/optics/lens.py",
             "_CHECK_AZIMUTHS_DEG = (90.0, 0.0) + tuple(22.5 * k for k in range(16) if k not in "
             "(0, 4))", "_CHECK_AZIMUTHS_DEG = (90.0,)", CROSSING),
    Mutation("crossing_radius_along_y", "the crossing radius bisected along y whatever the "
             "azimuth of the crossing", "deeplens/optics/lens.py",
             "        cos_a, sin_a = math.cos(azimuth), math.sin(azimuth)\n",
             "        cos_a, sin_a = 0.0, 1.0\n", CROSSING),
    Mutation("subpixel_cap_64", "the diffraction kernel's sub-pixel points capped at 64 again "
             "(a sharp PSF at coarse pixels under-integrated, a perfect lens refused)",
             "deeplens/render/diffraction.py",
             "        # no cap: beyond MAX_SUB_POINTS the transform integrates the pixel exactly "
             "(issue 38)\n", "        sub = min(sub, 64)\n", PIXEL),
    Mutation("exact_pixel_no_sinc", "the exact pixel integral without the pixel's transfer "
             "function (point samples of the intensity)", "deeplens/render/diffraction.py",
             "        sinc = torch.sinc(w * (pitch / (2 * math.pi)))\n",
             "        sinc = torch.ones_like(w)\n", PIXEL),
    Mutation("sampling_limit_blames_aberrations", "a PSF sharper than a pixel refused as an "
             "aberrated lens", "deeplens/render/diffraction.py",
             "        if spread + halo <= 1.0:\n", "        if False:\n", PIXEL),
    # ------------------------------------------------ rayoptics oracle, configurations (issue 37)
    Mutation("efl_mirror_sign", "the EFL's sign after an odd number of mirrors flipped "
             "(-1/u' for -sign(n')/u')", "deeplens/optics/paraxial.py",
             "        efl = -n[-1].sign() / uA\n", "        efl = -1.0 / uA\n", RAYOPTICS),
    Mutation("efl_reduced", "the EFL as 1/phi instead of the image-side n'/phi (an image in glass)",
             "deeplens/optics/paraxial.py", "        efl = -n[-1].sign() / uA\n",
             "        efl = -n[-1].sign() / (uA * n[-1].abs())\n", RAYOPTICS),
    Mutation("obna_as_slope", "OBNA's marginal ray given the slope sin(theta) instead of "
             "tan(theta)", "deeplens/optics/io/zmx_system.py",
             "            return 2.0 * abs(s + pos) * math.tan(theta)",
             "            return 2.0 * abs(s + pos) * math.sin(theta)", RAYOPTICS),
    Mutation("mconf_write_surface_off_by_one", "write_zmx_configs numbers a surface operand "
             "one surface on", "deeplens/optics/io/zmx_write_configs.py",
             "put(_SURFACE_OPERANDS[key], s, k, tb[1])",
             "put(_SURFACE_OPERANDS[key], s + 1, k, tb[1])", MCONF_WRITE),
    # ------------------------------------------------ glass choice in the design search
    Mutation("substitute_other_catalogue", "substitution candidates drawn from a catalogue "
             "the spec did not choose", "deeplens/design/search/glass.py",
             "i: nearest_glasses(*_model_values(lens.materials[i]), catalogues, k, v_weight, exclude)",
             "i: nearest_glasses(*_model_values(lens.materials[i]), \"OHARA\", k, v_weight, exclude)",
             GLASS_SEARCH + ("tests/design/search/test_glass.py",)),
    Mutation("model_glass_not_a_variable", "model glasses left out of the search's variables",
             "deeplens/design/search/refine.py", "glasses=glass_region is not None)",
             "glasses=False)", GLASS_SEARCH),
    Mutation("search_seed_ignored", "the starts' Sobol points not seeded",
             "deeplens/design/search/multistart.py",
             "scramble=True, seed=int(cfg.seed))", "scramble=True, seed=None)",
             GLASS_SEARCH + ("tests/design/search/test_multistart.py",)),
    Mutation("rank_keeps_the_worst", "ranked substitution candidates sorted worst first",
             "deeplens/design/search/glass.py", "scored.sort(key=lambda t: (t[0], t[1]))",
             "scored.sort(key=lambda t: (-t[0], t[1]))", SUBSTITUTION),
    Mutation("snap_without_pull", "the snap's pull strength ignored (no pull)",
             "deeplens/design/search/glass.py", "return self.strength * self.offset(n_d, v_d)",
             "return 0.0 * self.offset(n_d, v_d)", SUBSTITUTION),
    Mutation("substitution_keeps_unoptimised_lens", "the kept candidate is the lens before its "
             "re-optimisation", "deeplens/design/search/glass.py",
             "        val = float(reoptimize(cand))",
             "        val = float(reoptimize(copy.deepcopy(cand)))", SUBSTITUTION),
    Mutation("stop_shift_moves_the_lens", "place_stops moves the stop and everything behind "
             "it instead of the stop alone", "deeplens/design/search/refine.py",
             "                        lens.distances[k + 1].sub_(sign * step)",
             "                        pass", ("tests/design/search/test_refine_converge.py",)),
    Mutation("converge_rule_absolute", "the convergence rule compares a chunk's gain with tol "
             "itself, not tol times the merit", "deeplens/design/search/refine.py",
             "flat = flat + 1 if before - merit < tol * before else 0",
             "flat = flat + 1 if before - merit < tol else 0",
             ("tests/design/search/test_refine_converge.py",)),
    # ---------------------------------- session 12: re-balancing, the ceiling, the roof
    Mutation("rebalance_floor_ignored", "the re-balancing's floor ignored (a start gains below "
             "its thin system's third-order RMS)", "deeplens/design/search/thick_polish.py",
             "        r = rms if floor is None else torch.maximum(rms, floor)",
             "        r = rms", ("tests/design/search/test_thick_polish.py",)),
    Mutation("rebalance_efl_not_scaled", "the re-balanced systems not scaled back to the focal "
             "length", "deeplens/design/search/thick_polish.py",
             "        return ParaxialSystem(c / s[:, None], d * s[:, None], n, stop, primary), ok",
             "        return ParaxialSystem(c, d, n, stop, primary), ok",
             ("tests/design/search/test_thick_polish.py",)),
    Mutation("perfect_sensor_at_f", "the perfect lens's sensor at f, not at the scene's image "
             "distance f s / (s - f)", "deeplens/evaluation/perfect.py",
             "    v = f if math.isinf(s) else f * s / (s - f)", "    v = f",
             ("tests/training/test_perfect_variant.py",)),
    Mutation("travel_axis_not_reflected", "the traced axis not reflected by a mirror inside "
             "coordinate breaks (the mirror count's parity lost)", "deeplens/optics/frames.py",
             "            a = [a[k] - 2.0 * an * nv[k] for k in range(3)]", "            a = list(a)",
             ("tests/optics/io/test_zmx_prisms.py",)),
    # ---------------------------------- the union of the screen's two rankings (issue 36)
    Mutation("union_not_deduplicated", "the union of the plain and re-balanced rankings keeps a "
             "start found in both twice", "deeplens/design/search/screen.py",
             "            if i < len(top) and not any(same(top[i][3], o[3]) for o in out):",
             "            if i < len(top):", ("tests/design/search/test_screen_union.py",)),
    Mutation("union_is_rebalanced_only", "seidel_ranking='union' returns the re-balanced "
             "ranking alone", "deeplens/design/search/screen.py",
             '    if rebalance > 0 and ranking == "rebalanced":', "    if rebalance > 0:",
             ("tests/design/search/test_screen_union.py",)),
    Mutation("union_cut_to_starts", "the search refines only the first `starts` starts of the "
             "union", "deeplens/design/search/multistart.py",
             "        budget = max(budget, len(got))", "        budget = budget",
             ("tests/design/search/test_screen_union.py",)),
    # ------------------------------------------------ unseen real files (issue 37)
    Mutation("sqap_stop_floa_pupil_widened", "a SQAP on a lens stop under FLOA floats the "
             "pupil on the rectangle's half-diagonal, not the stop's DIAM",
             "deeplens/optics/io/zmx_surfaces.py", "        if s.stop and sd > 0:",
             "        if False:", ("tests/optics/io/test_zmx.py",)),
    Mutation("afocal_object_heights_refused", "an afocal system with a finite object refused "
             "for object-height fields and an OBNA", "deeplens/optics/io/zmx_read.py",
             "    needs_efl = ftyp[0] in (2, 3) or", "    needs_efl = True or",
             ("tests/optics/io/test_zmx.py",)),
    Mutation("flat_face_opening_not_decentred", "a decentred SQAP on a flat mirror read as a "
             "Plane (no off-vertex opening)", "deeplens/optics/io/surface_handlers.py",
             "        if flat and s.obdc is None:", "        if flat:",
             ("tests/optics/io/test_zmx.py",)),
    Mutation("json_vendor_glass_by_name", "a vendor glass written to a JSON lens file by name "
             "only (the file cannot be read back)", "deeplens/optics/io/lensfile.py",
             "    if not isinstance(m, (AGFGlass, BuchdahlGlass)):\n        return name",
             "    if True:\n        return name",
             ("tests/optics/io/test_lensfile_formula_glass.py",)),
    # ---------------------------- issue 36: the converged reference, sequential substitution
    Mutation("sequential_skips_reoptimisation", "the sequential substitution's candidates not "
             "re-optimised (scored as put in)", "deeplens/design/search/glass.py",
             "            v = _score(reoptimize, cand, row)",
             "            v = _score(lambda c: score(c) if score else 0.0, cand, row)",
             SUBSTITUTION),
    Mutation("loss_against_unconverged_model", "the substitution's loss measured against the "
             "model design as the search left it, not converged",
             "deeplens/design/search/glass_stage.py", "            ref = d2\n",
             "            pass\n", SUBSTITUTION),
    Mutation("real_design_not_converged", "the kept real-glass candidate not converged under "
             "the reference's rule", "deeplens/design/search/glass_stage.py",
             "max_rounds=cfg.converge_rounds)", "max_rounds=0)", SUBSTITUTION),
    Mutation("sequential_other_catalogue", "sequential substitution's candidates drawn from a "
             "catalogue the spec did not choose", "deeplens/design/search/glass.py",
             "for g, d in nearest_glasses(*_model_values(cur.materials[i]), catalogues, k,",
             "for g, d in nearest_glasses(*_model_values(cur.materials[i]), \"OHARA\", k,",
             GLASS_SEARCH),
    # issue 37, session 13 (files4): SURF-number skips, FLOA on a CLAP, the Zernike vertex
    Mutation("surf_skip_refs_ignored", "SURF numbers that skip one read in file order even "
             "when a line names a surface by number", "deeplens/optics/io/zmx_parse.py",
             "refs = [r for r in records if _names_a_surface(r)]", "refs = []", SURF_SKIP),
    Mutation("floa_clap_note_dropped", "a FLOA stop whose CLAP and DIAM differ floated on the "
             "CLAP without the note", "deeplens/optics/io/zmx_read.py",
             "s.clap is not None and s.diam > 0 and s.clap[0] != s.diam:",
             "s.clap is not None and s.diam > 0 and s.clap[0] == s.diam:", FLOA_CLAP),
    Mutation("zernike_vertex_terms_dropped", "the m = 0 Zernike terms left out of a Zernike "
             "sag's paraxial curvature", "deeplens/optics/surfaces/zernike_sag.py",
             "                cur = cur + 2.0 * norm(n, 0) * r2 * A / rn2",
             "                cur = cur + 0.0 * norm(n, 0) * r2 * A / rn2", ZERN_RAYOPTICS),
    # ----------------------------------------- issue 36: the combined substitution (default)
    Mutation("combined_keeps_the_worse", "the combined substitution keeps the worse of its "
             "sequential and ranked sets", "deeplens/design/search/glass.py",
             "    best = min(parts, key=lambda r: r.merit)",
             "    best = max(parts, key=lambda r: r.merit)", SUBSTITUTION),
    Mutation("combined_ranked_other_catalogue", "the combined substitution's ranked set drawn "
             "from a catalogue the spec did not choose", "deeplens/design/search/glass.py",
             "                lens, catalogues, reoptimize, k=m, v_weight=v_weight,",
             "                lens, \"SCHOTT\", reoptimize, k=m, v_weight=v_weight,",
             SUBSTITUTION),
    # ----------------------------------------- issue 37: CODE V decenters and tilts (seq2)
    Mutation("codev_ade_sign", "CODE V's ADE read as a right-handed tilt (its sign flipped in "
             "every break)", "deeplens/optics/io/codev_decenter.py",
             "        d[\"v\"][_VALUES.index(cmd)] = nums(args, line, cmd, 1)[0]\n",
             "        d[\"v\"][_VALUES.index(cmd)] = nums(args, line, cmd, 1)[0] * "
             "(-1 if cmd == \"ADE\" else 1)\n", CODEV_DECENTER),
    Mutation("codev_dar_no_return", "DAR read as a basic decenter (the frame not returned after "
             "the surface)", "deeplens/optics/io/codev_decenter.py",
             "        if typ == \"DAR\":\n            s[\"t\"] = 0.0\n            emit(s)\n"
             "            emit(_cb_item(_inverse(v, u), t_after - v[2], where))\n",
             "        if typ == \"DAR\":\n            emit(s)\n", CODEV_DECENTER),
    Mutation("codev_inverse_forward_order", "the inverse break of DAR and REV applied in the "
             "forward order (decenter, then tilt) instead of the reverse",
             "deeplens/optics/io/codev_decenter.py",
             "                  -math.radians(v[5]), order=1)",
             "                  -math.radians(v[5]), order=0)", CODEV_DECENTER),
    # ----------------------------------------- issue 37 item 5: the grid sag surface (GRID_SAG)
    Mutation("grid_sag_xy_swapped", "grid sag: x looked up along the grid's y and y along its "
             "x", "deeplens/optics/surfaces/grid_sag.py",
             "        sx, nx, hx = self._index(x, 0)\n        sy, ny, hy = self._index(y, 1)\n"
             "        ix, u = self._cell(sx, nx)\n        iy, v = self._cell(sy, ny)\n"
             "        G = ",
             "        sx, nx, hx = self._index(y, 0)\n        sy, ny, hy = self._index(x, 1)\n"
             "        ix, u = self._cell(sx, nx)\n        iy, v = self._cell(sy, ny)\n"
             "        G = ", ("tests/optics/surfaces/test_grid_sag.py",)),
    Mutation("grid_sag_slopes_per_cell", "grid sag: the node slopes taken per cell, not per mm "
             "(not multiplied by the cell size)", "deeplens/optics/surfaces/grid_sag.py",
             "out = out + (Z[jy, jx] * bu[a] * bv[b] + hx * Zx[jy, jx] * bu[2 + a] * bv[b]\n"
             "                             + hy * Zy[jy, jx] * bu[a] * bv[2 + b]",
             "out = out + (Z[jy, jx] * bu[a] * bv[b] + Zx[jy, jx] * bu[2 + a] * bv[b]\n"
             "                             + Zy[jy, jx] * bu[a] * bv[2 + b]",
             ("tests/optics/surfaces/test_grid_sag.py",)),
    Mutation("grid_sag_rows_from_bottom", "GRID_SAG: the file's rows read from -y up (they run "
             "from +y down)", "deeplens/optics/io/zmx_grid_sag.py",
             "grid = a[:, :4].reshape(ny, nx, 4).flip(0)", "grid = a[:, :4].reshape(ny, nx, 4)",
             ("tests/optics/io/test_zmx_grid_sag.py",)),
    Mutation("grid_sag_cross_derivative_units", "GRID_SAG: the cross derivative scaled like a "
             "length (it is per length)", "deeplens/optics/io/zmx_grid_sag.py",
             "zxy = grid[..., 3] / s_mm", "zxy = grid[..., 3] * s_mm",
             ("tests/optics/io/test_zmx_grid_sag.py",)),
    # ------------------------------------------ issue 37 (branch seq1): CODE V defaults, PRV
    Mutation("codev_no_sto_last_surface", "a .seq file without STO gets its stop on the last "
             "surface instead of the first", "deeplens/optics/io/codev.py",
             '        body[0]["stop"] = True', '        body[-1]["stop"] = True', CODEV_DEFAULTS),
    Mutation("codev_ref_default_last", "several WL without REF: the last wavelength taken as "
             "the reference instead of the first", "deeplens/optics/io/codev.py",
             "        ref = 1\n", "        ref = len(waves)\n", CODEV_DEFAULTS),
    Mutation("prv_spline_slope_sign", "a PRV glass's spline with the wrong sign of its "
             "curvature term in the slope", "deeplens/optics/io/codev_private.py",
             "    c1 = d - h * (2.0 * m[:-1] + m[1:]) / 6.0",
             "    c1 = d + h * (2.0 * m[:-1] + m[1:]) / 6.0", CODEV_DEFAULTS),
    Mutation("cir_obs_file_units", "CIR OBS radius not converted from the file's unit to mm",
             "deeplens/optics/io/codev.py", "_obscuration(lens, i, r * u, line,",
             "_obscuration(lens, i, r, line,", CODEV_DEFAULTS),
    Mutation("pik_factor_ignored", "a PIK pickup's factor ignored (target = source + offset)",
             "deeplens/optics/io/codev.py",
             "        set_surface_value(dst, p, factor * surface_value(src, q) + offset)",
             "        set_surface_value(dst, p, surface_value(src, q) + offset)", CODEV_DEFAULTS),
    Mutation("fno_finite_not_working", "FNO with a finite object: the EPD of twice the "
             "F-number", "deeplens/optics/io/codev.py",
             "    return abs(to_pupil) / (fno * abs(u_k))",
             "    return abs(to_pupil) / (2.0 * fno * abs(u_k))", CODEV_DEFAULTS),
    Mutation("yim_finite_magnification_inverted", "YIM with a finite object: the magnification "
             "inverted", "deeplens/optics/io/codev.py",
             "        m = abs(float(n[0]) / (float(n[-1]) * float(u_k)))",
             "        m = abs(float(n[-1]) * float(u_k) / float(n[0]))", CODEV_DEFAULTS),
    Mutation("codev_si_defocus_dropped", "SI's thickness (a defocus) not added to the last gap",
             "deeplens/optics/io/codev.py", "    d_sensor = gap + img[\"t\"] * u",
             "    d_sensor = gap", CODEV_CORPUS),
    # ------------------- multi-configuration operands of real files (issue 37 item 6, branch mconf)
    Mutation("mconf_pram_number_from_solve_column", "PRAM's parameter number read from the row's "
             "fifth field (the solve type) instead of its sixth", "deeplens/optics/io/zmx_mconf.py",
             "            second = int(r.tokens[5])", "            second = int(r.tokens[4])",
             MCONF_OPS),
    Mutation("mconf_apmn_sets_maximum", "APMN sets the aperture's maximum radius and APMX its "
             "minimum", "deeplens/optics/io/zmx_mconf.py",
             'lo, hi = (_repeat(lo, v), hi) if key == "APMN" else (lo, _repeat(hi, v))',
             'lo, hi = (lo, _repeat(hi, v)) if key == "APMN" else (_repeat(lo, v), hi)',
             MCONF_OPS),
    Mutation("mconf_sdia_ignored", "an SDIA row not applied (the saved semi-diameter kept)",
             "deeplens/optics/io/zmx_mconf.py",
             "        s.diam, s.diam_line = _repeat(s.diam, v), ln", "        s.diam_line = ln",
             MCONF_OPS),
    Mutation("mconf_stps_off_by_one", "STPS puts the stop on the surface before the one named",
             "deeplens/optics/io/zmx_mconf.py", "        surfs[int(v)].stop = True",
             "        surfs[int(v) - 1].stop = True", MCONF_OPS),
    Mutation("mconf_temperature_silent", "a configuration's temperature ignored without its note",
             "deeplens/optics/io/zmx_mconf.py", 'if v != (20.0 if key == "TEMP" else 1.0):',
             "if False:", MCONF_OPS),
    Mutation("mconf_rows_rounding_kept", "a row that repeats the saved value to its 13 digits "
             "replaces the saved 17-digit value (the active configuration is not the saved lens)",
             "deeplens/optics/io/zmx_mconf.py", "abs(saved - v) <= 5e-13 * abs(saved)",
             "abs(saved - v) < 0 * abs(saved)", MCONF_OPS),
    Mutation("mconf_write_pram_number_dropped", "write_zmx_configs writes PRAM rows without the "
             "parameter number (sixth field 0)", "deeplens/optics/io/zmx_write_configs.py",
             "tb[2], int(ta[1]), ta[2])", "tb[2], 0, ta[2])", MCONF_WRITE),
    Mutation("mconf_write_sdia_dropped", "write_zmx_configs writes no SDIA row for a differing "
             "DIAM (configuration 1's kept)", "deeplens/optics/io/zmx_write_configs.py",
             '                    put("SDIA", s, k, tb[1], 0, ta[1])', "                    pass",
             MCONF_WRITE),
    # issue 37, branch set5: the fifth unseen set's rules
    Mutation("tilted_mirror_z_normal", "a mirror reflects the traced axis about the local z "
             "axis, not its own vertex normal (a TILTSURF mirror)", "deeplens/optics/frames.py",
             "            nv = vertex_normal(s)\n            an =",
             "            nv = [0.0, 0.0, 1.0]\n            an =", SET5_RULES),
    Mutation("fixed_diam_clips_flat_plane", "a fixed DIAM on a flat plane in one medium clips "
             "(refusing an OBSC wider than it)", "deeplens/optics/io/zmx_surfaces.py",
             "    if (fixed and same_medium and (flat or handler.shape_only) and not s.stop\n",
             "    if (False and fixed and same_medium and not s.stop\n", SET5_RULES),
    Mutation("opening_written_without_clap", "an opening that is not the stop written with a "
             "fixed DIAM only (OpticStudio does not clip on it)", "deeplens/optics/io/zmx_write.py",
             "    if (isinstance(s, Aperture) and not is_stop and s.shape == \"circle\"",
             "    if (False and isinstance(s, Aperture) and not is_stop and s.shape == \"circle\"",
             SET5_RULES),
    Mutation("binary2_power_halved", "a Binary 2 phase's paraxial power halved (2π for π in "
             "-M A_1 λ / (π R_n²))", "deeplens/optics/surfaces/binary2.py",
             "(float(wavelength_nm) * 1e-6) / (math.pi * rn.to(a1) ** 2)",
             "(float(wavelength_nm) * 1e-6) / (2.0 * math.pi * rn.to(a1) ** 2)",
             BINARY2_RAYOPTICS),
    Mutation("infrared_coefficient_changed", "a coefficient of an INFRARED crystal mistyped "
             "(germanium's second Sellmeier B 14.5142535 as 14.5142355)",
             "deeplens/optics/io/infrared_glass.py", "(14.5142535, 0.1626427)",
             "(14.5142355, 0.1626427)", IRGLASS),
    Mutation("infrared_range_um_as_nm", "an INFRARED crystal's range in µm taken as nm (no "
             "×1000)", "deeplens/optics/io/infrared_glass.py",
             "(lo * 1000.0, hi * 1000.0)", "(lo, hi)", IRGLASS),
    Mutation("klein_pole_not_squared", "ZnS's Klein formula with the pole λ_i for λ_i² (a "
             "length for an area: µm for µm²)", "deeplens/optics/io/infrared_glass.py",
             "c2, c4 = l1 * l1, l2 * l2", "c2, c4 = l1, l2", IRGLASS),
    Mutation("infrared_use_silent", "an INFRARED crystal used without the located note naming "
             "its source", "deeplens/optics/io/zmx_glass.py",
             'p.note(s.glass_line, f"glass {glass!r}: {_SOURCE_NOTES[cat](glass)}")', "pass",
             IRGLASS),
    # ----------------------------------------- issue 37 item 5: OpticStudio's Irregular surface
    Mutation("irregular_coma_sign", "irregular surface: the coma term Zc applied with the wrong "
             "sign (in the sag and its slopes alike)", "deeplens/optics/surfaces/irregular.py",
             "zs, za, zc = self.zs.to(xs), self.za.to(xs), self.zc.to(xs)",
             "zs, za, zc = self.zs.to(xs), self.za.to(xs), -self.zc.to(xs)", IRREGULAR),
    Mutation("irregular_terms_from_x", "irregular surface: astigmatism and coma oriented from the "
             "x axis instead of the y axis (θ = 0 puts them along x)",
             "deeplens/optics/surfaces/irregular.py", "w = v * ct + u * st", "w = u * ct + v * st",
             IRREGULAR),
    Mutation("parax_xy_powers_swapped", "PARAX_XY: PARM 1 read as the y power and PARM 2 as the x "
             "power", "deeplens/optics/io/surface_handlers.py",
             "px, py = (s.parm.get(i, (0.0, 0))[0] / ctx.s_mm for i in (1, 2))",
             "px, py = (s.parm.get(i, (0.0, 0))[0] / ctx.s_mm for i in (2, 1))", PARAX_XY),
    # ------------------- CODE V rectangular apertures (issue 37, branch seq3)
    Mutation("codev_rex_full_width", "CODE V's REX/REY read as full widths (half-widths halved)",
             "deeplens/optics/io/codev_apertures.py",
             '    hx, hy = r[sizes[0]][0] * u, r[sizes[1]][0] * u',
             '    hx, hy = r[sizes[0]][0] * u / 2, r[sizes[1]][0] * u / 2', CODEV_APERTURES),
    Mutation("codev_ady_sign", "CODE V's ADX/ADY read as the negated aperture centre",
             "deeplens/optics/io/codev_apertures.py",
             '    dec = (r["ADX"][0] * u if "ADX" in r else 0.0, r["ADY"][0] * u if "ADY" in r '
             'else 0.0)',
             '    dec = (-r["ADX"][0] * u if "ADX" in r else 0.0, -r["ADY"][0] * u if "ADY" in r '
             'else 0.0)', CODEV_APERTURES),
    Mutation("codev_decentred_image_focus_shift_dropped", "a decentred image's SI thickness (its "
             "focus shift) dropped", "deeplens/optics/io/codev_decenter.py",
             '        place(_forward(v, u), image, where, s["t"] if image else 0.0)',
             '        place(_forward(v, u), image, where, 0.0)', CODEV_APERTURES),
    # ------------------- CODE V zoom positions (issue 37, branch seq3)
    Mutation("codev_zoom_off_by_one", "zoom position N read with the values of position N + 1 "
             "(the last for N = n)", "deeplens/optics/io/codev_zoom.py",
             "        v = vals[position - 1]", "        v = vals[min(position, n - 1)]",
             CODEV_ZOOM),
    Mutation("codev_zoom_not_shared", "read_seq_zooms shares no surface between the positions",
             "deeplens/optics/io/codev.py", "    share_surfaces(lenses)\n    for k, lens in "
             "enumerate(lenses, start=1):\n        try:\n            lens.check()\n        "
             "except ValueError as e:\n            rd.fail(",
             "    for k, lens in enumerate(lenses, start=1):\n        try:\n            "
             "lens.check()\n        except ValueError as e:\n            rd.fail(", CODEV_ZOOM),
    Mutation("codev_zoom_field_ignored", "a zoomed field (ZOO YAN Fk) not applied",
             "deeplens/optics/io/codev_zoom.py", "            fv[k - 1] = v\n",
             "            pass\n", CODEV_ZOOM),
    # ------------------------------------------ issue 37 item 2: Corning's C79-80 (HPFS 7980)
    Mutation("corning_range_to_tan", "C79-80 given the 6.7 µm of Tan's check of silica instead "
             "of Malitson's own 0.21-3.71 µm", "deeplens/optics/io/corning_glass.py",
             "range_nm=(210.0, 3710.0),", "range_nm=(210.0, 6700.0),", CORNING),
    Mutation("corning_use_silent", "C79-80 used without the located note naming its source",
             "deeplens/optics/io/zmx_glass.py",
             '_SOURCE_NOTES = {"INFRARED": crystal_note, "CORNING": corning_note,',
             '_SOURCE_NOTES = {"INFRARED": crystal_note,', CORNING),
    Mutation("corning_not_searched_elsewhere", "C79-80 not found for a file whose GCAT names "
             "another catalogue (OpTaliX's SPECIAL)", "deeplens/optics/io/vendor_glass.py",
             '    hits += ["CORNING"] if _key(glass) in CORNING_GLASSES else []\n', "", CORNING),
    Mutation("corning_partial_said_shipped", "a Corning glass deeplens lacks refused as 'not in "
             "the shipped CORNING catalogue' (no CORNING.agf asked for)",
             "deeplens/optics/io/zmx_glass.py",
             "(c not in CURRENT_CATALOGUES or (gcat and c in PARTIAL_CATALOGUES))",
             "c not in CURRENT_CATALOGUES", CORNING),
    # issue 37, branch set6: the sixth unseen set's readings
    Mutation("even_r2_paraxial_dropped", "an even asphere's r² term left out of its paraxial "
             "curvature (CURV alone)", "deeplens/optics/surfaces/odd_asphere.py",
             "            return self.c + 2.0 * self.a[1]", "            return self.c",
             SET6_RULES),
    Mutation("oracle_floa_epd_signed", "the corpus oracle keeps optiland's signed float-by-stop "
             "EPD (negative on a mirror stop met below the axis)",
             "tests/optics/io/test_zmx_corpus.py",
             "value=abs(float(torch.as_tensor(optic.paraxial.EPD()).reshape(-1)[0])))",
             "value=(float(torch.as_tensor(optic.paraxial.EPD()).reshape(-1)[0])))",
             SET6_RULES),
    Mutation("rect_stop_resized_to_pupil", "a rectangular stop under an EPD aperture shrunk or "
             "grown to the pupil's radius (its rectangle scaled with the semi-diameter)",
             "deeplens/optics/lens.py",
             "        with torch.no_grad():\n            stop.semi_diameter.fill_(sd)\n",
             "        with torch.no_grad():\n            stop.semi_diameter.fill_(sd)\n"
             "            if getattr(stop, \"shape\", \"circle\") == \"rect\":\n"
             "                f = sd / float(torch.linalg.vector_norm(stop.half_widths))\n"
             "                stop.half_widths.mul_(f)\n",
             SET6_RULES),
    # ------------------- elliptical apertures and obscurations (issue 37, branch ellipse)
    Mutation("ellipse_half_axes_swapped", "an ellipse's half-axes swapped (a along y, b along x)",
             "deeplens/optics/openings.py", "    u, v = X / half_axes[0], Y / half_axes[1]",
             "    u, v = X / half_axes[1], Y / half_axes[0]", ELLIPSE),
    Mutation("elap_read_as_y_then_x", "ELAP's numbers read as (y half-axis, x half-axis)",
             "deeplens/optics/io/zmx_parse.py", "        cur.elap = (a, b, ln)",
             "        cur.elap = (b, a, ln)", ELLIPSE),
    Mutation("ellipse_obscuration_inverted", "an elliptical obscuration passes the rays inside "
             "it and blocks those outside", "deeplens/optics/surfaces/base.py",
             "        opening = opening - Ellipse(obs, check=False)",
             "        opening = opening & Ellipse(obs, check=False)", ELLIPSE),
    # ------------------------------- issue 37: a Qbfs on a conic base (Forbes' generalisation)
    Mutation("qbfs_conic_warning_dropped", "a Qbfs on a conic base loaded without the located "
             "warning naming the reading and the option", "deeplens/optics/io/surface_handlers.py",
             "        p.note_each(s.type_line, QBFS_CONIC_CAUSE,",
             "        (lambda *a: None)(s.type_line, QBFS_CONIC_CAUSE,", QBFS_CONIC),
    Mutation("qbfs_conic_option_ignored", "qbfs_conic='refuse' ignored (the surface loaded "
             "anyway)", "deeplens/optics/io/surface_handlers.py",
             '        if qbfs_conic == "refuse":', '        if False:', QBFS_CONIC),
    # --------------- issue 37: the corpus oracles given deeplens' GRID_SAG paraxial rule
    Mutation("grid_sag_paraxial_one_cell", "grid sag: the paraxial curvature across a grid line "
             "through the vertex taken from one cell, not the mean of the two cells'",
             "deeplens/optics/surfaces/grid_sag.py",
             "            shifts.append(-1)   # on a grid line inside the grid: both cells",
             "            pass   # planted: one cell only",
             ("tests/optics/io/test_zmx_oracle_stand_ins.py",)),
    # ------------------------------- issue 37: a stop on a coordinate break (a turn about z)
    Mutation("stop_on_break_gap_counted_twice", "the gap before a stop on a break also put "
             "between the stop and the break (the break and all after it moved along the axis)",
             "deeplens/optics/io/zmx_read.py",
             "                gap = 0.0                # the break's vertex is the stop's",
             "                pass", STOP_ON_BREAK),
    Mutation("clap_beyond_diam_kept", "an annular CLAP's unbounded outer radius (CLAP 4 1e10) "
             "taken as the surface's semi-diameter instead of giving way to its DIAM",
             "deeplens/optics/io/zmx_surfaces.py", "    s.clap = None\n", "    pass\n",
             CLAP_BEYOND_DIAM),
    # ------------------------------- issue 37: SPID, a spider obscuration
    Mutation("spider_arms_half_spacing", "a spider's arms turned by half their spacing (the "
             "first arm between +x and the second instead of along +x)",
             "deeplens/optics/openings.py",
             "t = (self.angle.to(torch.float64).to(x.device) + 2.0 * math.pi * j / self.n_arms)",
             "t = (self.angle.to(torch.float64).to(x.device) + math.pi * (2 * j + 1) / self.n_arms)",
             ("tests/optics/io/test_zmx_spider.py",)),
    Mutation("spider_width_as_half_width", "a spider's arm width taken as its half-width (arms "
             "twice as wide)", "deeplens/optics/openings.py",
             "        half = 0.5 * self.width.to(x)\n", "        half = self.width.to(x)\n",
             ("tests/optics/io/test_zmx_spider.py",)),
    # ------------------------- issue 37: withdrawn SCHOTT BK7 before the visible-only fit
    Mutation("withdrawn_bk7_skipped", "the withdrawn SCHOTT entries never consulted under GCAT "
             "(BK7 falls to Robb & Mercado's 400-700 nm fit)", "deeplens/optics/io/zmx_glass.py",
             '(WITHDRAWN_CATALOGUES, withdrawn_glass, "withdrawn",',
             '((), withdrawn_glass, "withdrawn",',
             ("tests/optics/io/test_withdrawn_glass.py",)),
    # ------------------------- issue 37: two-point holograms (HOLOGRM1, HOLOGRM2)
    Mutation("hologram_wavelength_ratio_inverted", "a hologram's kick scaled by λ_c/λ instead "
             "of λ/λ_c (the same at the construction wavelength, wrong at any other)",
             "deeplens/optics/surfaces/hologram.py",
             "return self.order * w / self.wl_c.to(like)",
             "return self.order * self.wl_c.to(like) / w",
             ("tests/optics/surfaces/test_hologram.py",)),
    Mutation("hologram1_sense_flipped", "HOLOGRM1's grating vector negated (u_1 - u_2: a ray "
             "from point 1 no longer leaves as if from point 2)",
             "deeplens/optics/surfaces/hologram.py",
             "return -(u1 + u2) if self.kind == 2 else u2 - u1",
             "return -(u1 + u2) if self.kind == 2 else u1 - u2",
             ("tests/optics/surfaces/test_hologram.py",)),
    # ------------------------------- issue 37: gradient-index media (GRINSUR1)
    Mutation("grin_gradient_sign", "the Gradient 1 medium's n grad n with the sign of nr2 "
             "flipped (a focusing rod traced as a diverging one)", "deeplens/optics/grin.py",
             "        k = 2.0 * nr2 * n\n", "        k = -2.0 * nr2 * n\n",
             ("tests/optics/test_grin.py",)),
    Mutation("grin_paraxial_g_sign", "the rod's paraxial matrix with C = +n0 g sin gL (the "
             "sign of the gradient's power flipped)", "deeplens/optics/grin.py",
             "    return c, length * s / n0, -n0 * g2 * length * s, c\n",
             "    return c, length * s / n0, n0 * g2 * length * s, c\n",
             ("tests/optics/test_grin.py",)),
    Mutation("grin_exit_axial_index", "the exit refraction out of a graded medium with its "
             "axial index n0 instead of the local index at the hit",
             "deeplens/optics/grin_trace.py",
             "        n1 = torch.where(hit.valid, local_index(lens, before - 1, x, z), n1.to(x))\n",
             "        n1 = n1.to(x)\n", ("tests/optics/test_grin.py",)),
    # ------------------------- issue 37: ball lenses (full hemispheres, DIAM = |R|)
    Mutation("hemisphere_rim_refused", "a semi-diameter on the rim of its conic's domain (a "
             "ball lens's hemisphere, DIAM = |R|) refused as beyond it, as before branch ball",
             "deeplens/optics/surfaces/base.py",
             "    if 1.0 - (1.0 + k) * c * c * sd * sd < -CONIC_RIM_EPS * 2.0 ** -52:",
             "    if 1.0 - (1.0 + k) * c * c * sd * sd <= 0:",
             ("tests/optics/io/test_zmx_ball_lens.py",)),
    Mutation("conic_rim_sag_halved", "the conic's root taken as 1 on the rim of its domain (a "
             "hemisphere's rim sag R/2: faces crossing at a ball's rim pass the check)",
             "deeplens/optics/surfaces/asphere.py",
             "    rim = arg >= -CONIC_RIM_EPS * torch.finfo(arg.dtype).eps\n",
             "    rim = arg > 1.0\n",
             ("tests/optics/io/test_zmx_ball_lens.py",)),
    # ------------------------- issue 37: a FLOA stop without DIAM floats to the limiting aperture
    Mutation("floating_stop_loosest_aperture", "a stop with no semi-diameter under FLOA sized by "
             "the loosest fixed aperture (the largest ratio of semi-diameter to marginal-ray "
             "height) instead of the limiting one", "deeplens/optics/io/zmx_stop_size.py",
             "        if m < best:\n", "        if best == math.inf or m > best:\n",
             ("tests/optics/io/test_zmx_floa_stop_limit.py",)),
    # ------------------------- issue 37: the seventh unseen set (ideal lens after a mirror)
    Mutation("ideal_lens_power_signed_index", "an ideal lens's paraxial power 1/f times the signed "
             "index (a lens after a mirror diverges in the paraxial data, converges in the trace)",
             "deeplens/optics/paraxial.py",
             "        return surface.paraxial_power() * abs(n2)\n",
             "        return surface.paraxial_power() * n2\n",
             ("tests/optics/io/test_zmx_set7_rules.py",)),
    Mutation("oracle_keeps_old_wavl", "the oracle copy keeps an old WAVL list beside WAVM "
             "records (optiland 0.6 fails on it)", "tests/optics/io/test_zmx_corpus.py",
             '        text = re.sub(r"^(WAVL|WWGT)\\s.*\\n", "", text, flags=re.M)\n',
             "        pass\n",
             ("tests/optics/io/test_zmx_set7_rules.py",)),
    # ------------------------- issue 37: FRESNELS, OpticStudio's Fresnel surface (set 7)
    Mutation("fresnel_plane_normal", "a Fresnel surface refracting about its plane substrate's "
             "normal instead of its facet profile's", "deeplens/optics/surfaces/fresnel.py",
             "        return self.facet.normal(on_facet)\n",
             "        return super().normal(x)\n",
             ("tests/optics/io/test_zmx_fresnel.py",)),
    Mutation("fresnel_r2_on_r1", "a Fresnel surface's PARM 1 (the facets' r² term) put on r¹ "
             "(no paraxial power)", "deeplens/optics/surfaces/fresnel.py",
             "        radial[1::2] = coefficients", "        radial[0::2] = coefficients",
             ("tests/optics/io/test_zmx_fresnel.py",)),
    # ------------------------- issue 37: fixed semi-diameters that cross are limited as automatic ones
    Mutation("fixed_crossing_refused", "two surfaces whose fixed DIAMs cross refused again (only "
             "automatic semi-diameters limited where the faces meet)",
             "deeplens/optics/io/zmx_read.py",
             "    return _estimated(kept, stop_idx, i) or _fixed_diam(kept, stop_idx, i)\n",
             "    return _estimated(kept, stop_idx, i)\n",
             ("tests/optics/io/test_zmx_fixed_crossing.py",)),
    Mutation("floating_stop_sized_by_crossing_limits", "a FLOA stop without DIAM sized by the "
             "semi-diameters the reader limited where faces cross, not by the file's own",
             "deeplens/optics/io/zmx_stop_size.py",
             "        m = (original or {}).get(i, float(lens.surfaces[i].semi_diameter)) / heights[i]\n",
             "        m = float(lens.surfaces[i].semi_diameter) / heights[i]\n",
             ("tests/optics/io/test_zmx_fixed_crossing.py",)),
    # ------------------------- issue 37: a material pickup (GLAS ... 2 k) takes SURF k's material (set 8)
    Mutation("glass_pickup_read_as_model", "a material pickup (GLAS ___BLANK 2 k 1.5 40) read as a "
             "model glass of the numbers written on its line, not SURF k's material",
             "deeplens/optics/io/zmx_parse.py",
             '    if code == "2":   # the Pickup material solve: the glass of an earlier surface\n',
             '    if code == "-2":   # the Pickup material solve: the glass of an earlier surface\n',
             ("tests/optics/io/test_zmx_set8_rules.py",)),
    # ------------------------- issue 37: object set-ups (tilted object, object at a break)
    Mutation("object_tilt_ignored", "a tilted object plane's slope ignored (field points on "
             "the untilted plane)", "deeplens/optics/sampling.py",
             '    den = 1.0 - tx * tan[:, 0] - ty * tan[:, 1]\n',
             '    den = 1.0 + 0.0 * tx * ty * tan[:, 0]\n',
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("tilted_object_height_mirrored", "an object height on a tilted plane placed "
             "mirrored (+h as a positive field angle, the untilted convention)",
             "deeplens/optics/io/zmx_system.py",
             "out.append(0.0 - math.degrees(math.atan(h / den)))",
             "out.append(math.degrees(math.atan(h / den)))",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("edge_on_mirror_keeps_direction", "an axis meeting a mirror edge-on leaves it "
             "unturned (the sign after it kept)", "deeplens/optics/frames.py",
             "a = [0.0, 0.0, -float(out[-1])]", "a = [0.0, 0.0, float(out[-1])]",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("wavefront_launch_untilted", "the wavefront's launch draws a field's rays from the "
             "untilted object plane", "deeplens/analysis/wavefront.py",
             "/ (1.0 - ty * math.tan(th))", "/ 1.0",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("normalized_depth_untilted", "normalised rays' slopes use the untilted object "
             "plane's depth", "deeplens/optics/normalized.py",
             "(u - q[:, :2]) / (z_ep - q[:, 2:])",
             "(u - q[:, :2]) / (z_ep - float(lens.z_vertices()[0]) + s)",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("mirror_across_frame_lost", "a conic mirror lit across its frame takes only the "
             "crossing in the ray's own direction of travel (half the beam lost)",
             "deeplens/optics/lens.py", "backward=back, across=mirror)", "backward=back)",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    Mutation("wavefront_pivot_object_virtual", "the wavefront's launch takes an object at a "
             "break's pivot (distance 0) as virtual (rays start before it)",
             "deeplens/analysis/wavefront.py",
             "if float(z_obj) <= float(lens.z_vertices()[0]):", "if s > 0:",
             ("tests/optics/io/test_zmx_object_setups.py",)),
    # ------------------------------- issue 37: MISC's WATER (Daimon & Masumura 2007), branch misc
    Mutation("water_index_absolute", "WATER's absolute (vacuum) index used as is, not relative "
             "to OpticStudio's air as the catalogues hold it (n_D 1.33335 for 1.33299)",
             "deeplens/optics/io/misc_glass.py",
             "        return super()._index(w * n_air) / n_air\n",
             "        return super()._index(w)\n", ("tests/optics/io/test_misc_glass.py",)),
    Mutation("water_use_silent", "WATER used without the located note naming its source",
             "deeplens/optics/io/zmx_glass.py",
             '                p.note(s.glass_line, f"glass {glass!r}: {note(glass)}")\n',
             "                pass\n", ("tests/optics/io/test_misc_glass.py",)),
    # ------------------------- issue 37: a CLAP on a flat stop narrower than the system aperture's stop
    Mutation("flat_stop_clap_ignored", "a CLAP on a flat stop in air narrower than the stop the "
             "ENPD/OBNA gives ignored (the stop stays an Aperture of the paraxial radius: no "
             "vignetting)",
             "deeplens/optics/io/zmx_read.py",
             "            stop = flat_stop_as_asphere(lens)\n",
             "            return\n",
             ("tests/optics/io/test_zmx_flat_stop_clap.py",)),
    Mutation("flat_stop_pupil_shrunk_to_clap", "the stop's semi-diameter set to a narrower CLAP "
             "(the pupil shrinks to it) instead of the CLAP vignetting the system aperture's pupil",
             "deeplens/optics/io/zmx_read.py",
             "            stop.clear_radius.fill_(clap)\n",
             "            stop.clear_radius.fill_(clap)\n            stop.semi_diameter.fill_(clap)\n",
             ("tests/optics/io/test_zmx_flat_stop_clap.py",)),
    # ------------------- issue 37: object heights on an untilted object (branch objsign)
    Mutation("object_height_mirrored", "an object height on an untilted object placed mirrored "
             "(+h at y = -h, a positive field angle: the reading before branch objsign)",
             "deeplens/optics/io/zmx_system.py",
             "out.append(-math.degrees(math.atan(h / den)) + 0.0)",
             "out.append(math.degrees(math.atan(h / den)) + 0.0)",
             ("tests/optics/io/test_zmx_object_height_sign.py",)),
    Mutation("codev_yob_mirrored", "CODE V's YOB object height placed mirrored (+h at y = -h)",
             "deeplens/optics/io/codev.py",
             "return [0.0 - math.degrees(math.atan(h * u / d)) for h in vals]",
             "return [math.degrees(math.atan(h * u / d)) for h in vals]",
             ("tests/optics/io/test_zmx_object_height_sign.py", "tests/optics/io/test_codev.py")),
    Mutation("ftyp3_axis_images_at_zero", "a real image height solved as if the axial field's "
             "chief ray landed at 0 (a decentred lens's heights measured from the wrong point)",
             "deeplens/optics/io/zmx_system.py", "    y0 = chief_height(lens, 0.0)\n",
             "    y0 = 0.0 * chief_height(lens, 0.0)\n",
             ("tests/optics/io/test_zmx_object_height_sign.py",)),
    # ------------------------- issue 37: SCBD, a surface's own tilt/decenter (branch scbd)
    Mutation("scbd_reverse_not_inverted", "an SCBD after-surface 'reverse' taken as the before "
             "values negated in the same order (not the exact inverse, whose order is flipped)",
             "deeplens/optics/io/zmx_scbd.py",
             "    return tuple(-v for v in vals), 1 - order, \"reverse\"\n",
             "    return tuple(-v for v in vals), order, \"reverse\"\n",
             ("tests/optics/io/test_zmx_scbd.py",)),
    # ------------- issue 37: set 9, a Jones matrix plane in the oracles' dummy test (setup9)
    Mutation("oracle_jones_plane_not_plain", "the corpus oracles' plain-plane test knows "
             "STANDARD only: a JONESMAT at DISZ 0 before a lens face takes the glass, the face "
             "does not refract (optiland and rayoptics EFL 20 vs the thick lens's 10.67)",
             "tests/optics/io/test_zmx_corpus.py",
             "out.append(t in (\"STANDARD\", \"JONESMAT\") and",
             "out.append(t == \"STANDARD\" and", JONESMAT),
    Mutation("unset_aperture_generic_message", "an ENPD 0 / FNUM 0 (an unset aperture) refused "
             "with the lens's generic message, not naming the record and why",
             "deeplens/optics/io/zmx_read.py",
             "    if ap_type in (\"epd\", \"fno\") and not ap_value > 0:\n",
             "    if False:\n", SET9_RULES),
    Mutation("image_on_curved_vertex_sag_sign", "the sag of a curved last surface under an image "
             "at DISZ 0 taken with the wrong sign (a face convex towards the image loaded, one "
             "concave towards it refused)",
             "deeplens/optics/io/zmx_read.py",
             "    z = sign * z.to(torch.float64)\n", "    z = -sign * z.to(torch.float64)\n",
             SET9_RULES),
    Mutation("grating_axis_zeroth_order", "the traced axis leaves a grating in its zeroth order "
             "(a mirror's), not the order the file traces",
             "deeplens/optics/frames.py",
             "    return [float(v) for v in out[0]] if bool(ok[0]) else a\n",
             "    return a\n", SET9_RULES),
    # ------------------- issue 37: obscurations and the semi-diameter (branch aper9)
    Mutation("fixed_diam_clips_on_curved_dummy", "a fixed DIAM on a curved surface in one "
             "medium (no power; an OBSC beside it) taken as a clipping semi-diameter (OpticStudio "
             "applies its floating aperture only on a surface with refractive power)",
             "deeplens/optics/io/zmx_surfaces.py",
             "    if (fixed and same_medium and (flat or handler.shape_only) and not s.stop\n",
             "    if (fixed and same_medium and flat and not s.stop\n",
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    Mutation("ring_past_rim_refused", "a ring obscuration (OBSC r_i r_o) reaching past the "
             "semi-diameter refused as a central obscuration would be",
             "deeplens/optics/surfaces/aperture.py",
             "ri == 0.0 and not obscuration < float(semi_diameter))):",
             "not obscuration < float(semi_diameter))):",
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    Mutation("automatic_diam_past_edge_unexplained", "an automatic DIAM beyond the sphere's edge "
             "left to the built lens's domain error (at the SURF line, not saying that the DIAM is "
             "OpticStudio's footprint of a beam that misses the surface)",
             "deeplens/optics/io/zmx_surfaces.py",
             "        _automatic_diam_in_domain(s, k, surf, s_mm, p)\n",
             "        pass\n",
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    Mutation("usersurf_dll_not_named", "a USERSURF refused without naming the compiled plug-in "
             "(the DLL) it needs",
             "deeplens/optics/io/zmx_parse.py",
             'dll = f"plug-in {toks[2]}" if len(toks) > 2 else',
             'dll = "plug-in" if len(toks) > 2 else',
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    # ------------------- issue 37: Extended Polynomial, Birefringent In (branch xpoly)
    Mutation("xpolynom_term_order_reversed", "OpticStudio's polynomial terms taken from y^d "
             "down to x^d within a degree (x and y swapped: y, x, y², xy, x², ...)",
             "deeplens/optics/surfaces/extended_polynomial.py",
             "        out += [(d - i, i) for i in range(d + 1)]\n",
             "        out += [(i, d - i) for i in range(d + 1)]\n",
             ("tests/optics/io/test_zmx_xpolynom.py",)),
    Mutation("xpolynom_rn_power", "the normalisation radius applied once too few times "
             "(A / R^(i+j-1))", "deeplens/optics/io/surface_handlers.py",
             "        coeffs.append(a * s_mm / R ** (px + py))\n",
             "        coeffs.append(a * s_mm / R ** max(px + py - 1, 0))\n",
             ("tests/optics/io/test_zmx_xpolynom.py",)),
    Mutation("extended_polynomial_slope_unnormalised", "an Extended Polynomial's slopes not "
             "divided by the normalisation radius (the sag right, the normals wrong)",
             "deeplens/optics/surfaces/extended_polynomial.py",
             "            return W, Wu / rn, Wv / rn\n", "            return W, Wu, Wv\n",
             ("tests/optics/io/test_zmx_xpolynom.py",)),
    Mutation("birefringent_extraordinary_traced", "a birefringent-in surface in an extraordinary "
             "mode read as the ordinary ray's plain glass", "deeplens/optics/io/surface_handlers.py",
             "        if ray == \"extraordinary\":\n",
             "        if False:\n",
             ("tests/optics/io/test_zmx_birefringent.py",)),
    # ------------------------- issue 37: Zernike Fringe Phase, FZERNPHA (branch fzern)
    Mutation("fzernpha_radians", "the Zernike Fringe phase's coefficients taken as radians (no "
             "2π: OpticStudio's are waves) in the phase and the ray's kick",
             "deeplens/optics/surfaces/zernike_phase.py",
             "    phase_unit = 2.0 * math.pi\n",
             "    phase_unit = 1.0\n",
             ("tests/optics/io/test_zmx_zernike_phase.py",)),
    Mutation("fzernpha_noll_order", "the Zernike Fringe phase evaluated in Noll's (Standard) "
             "order and normalisation instead of the Fringe set",
             "deeplens/optics/surfaces/zernike_phase.py",
             "self.zernike, slopes, \"fringe\")",
             "self.zernike, slopes, \"standard\")",
             ("tests/optics/surfaces/test_zernike_fringe_phase.py",)),
    # ------------- issue 37: merging aper9 with fzern, a fixed DIAM on a surface with power in air
    Mutation("fixed_diam_never_clips_in_one_medium", "a fixed DIAM on any surface in one medium "
             "read as not clipping, an ideal lens's, phase's or grating's in air included (they "
             "have power there, and OpticStudio's floating aperture clips)",
             "deeplens/optics/io/zmx_surfaces.py",
             "(flat or handler.shape_only) and not s.stop",
             "(flat or True) and not s.stop",
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    # ------------- issue 37: a mirror turned about a pivot (break, +d, break, -d, mirror)
    Mutation("pivot_ahead_sign_flipped", "a surface after coordinate breaks accepted when its "
             "vertex lies behind the previous surface along the beam instead of ahead of it "
             "(the pivot refused, a slip of sign accepted)",
             "deeplens/optics/lens.py",
             "if ahead is not None and ahead[1] > 0:",
             "if ahead is not None and ahead[1] < 0:",
             ("tests/optics/io/test_zmx_pivot.py",)),
    # ------------------------------------------ issue 37: review of the lens-file work (review16)
    Mutation("diffract_axis_float64_cpu", "the traced axis diffracted with float64 CPU tensors "
             "whatever the surface's dtype and device (a lens on a GPU fails in every paraxial "
             "computation)", "deeplens/optics/frames.py",
             "        x = torch.zeros(1, 3, **kw)\n",
             "        x = torch.zeros(1, 3, dtype=torch.float64)\n",
             ("tests/optics/io/test_zmx_set9_rules.py",)),
    Mutation("fresnel_not_shape_only", "a Fresnel surface (FRESNELS) taken as having power in "
             "one medium (its fixed DIAM in air clips)", "deeplens/optics/io/zmx_fresnel.py",
             "    shape_only = True\n", "    shape_only = False\n",
             ("tests/optics/io/test_zmx_set9_apertures.py",)),
    Mutation("xy_radial_without_binomials", "an even degree of an XY or Extended polynomial taken "
             "as radial when its even terms are equal, not (x² + y²)^k's binomial multiples "
             "(x⁴ + x²y² + y⁴ called symmetric)", "deeplens/optics/surfaces/xy_polynomial.py",
             "cs.get((d - 2 * m, 2 * m), 0.0) - a * math.comb(k, m))",
             "cs.get((d - 2 * m, 2 * m), 0.0) - a)",
             ("tests/optics/io/test_zmx_xpolynom.py",)),
    # ------------------------------------ issue 37: Binary 1, BINARY_1 (branch binary1)
    Mutation("binary1_terms_y_first", "the Binary 1 phase's terms taken y first within a degree "
             "(y, x, y², xy, x², ...) instead of OpticStudio's x first",
             "deeplens/optics/surfaces/binary1.py",
             "        self.exponents = extended_terms(len(self.poly))\n",
             "        self.exponents = [(j, i) for i, j in extended_terms(len(self.poly))]\n",
             ("tests/optics/io/test_zmx_binary1.py",)),
    # issue 37, branch quartz: OpticStudio's BIREFRINGENT QUARTZ (ordinary index)
    Mutation("quartz_extraordinary_index", "QUARTZ given Radhakrishnan's extraordinary-ray "
             "coefficients (the e-ray index, 9e-3 higher) instead of the ordinary ray's",
             "deeplens/optics/io/birefringent_glass.py",
             "Crystal(11, (0.663044, 0.0036, 0.517852, 0.011236, 0.175912, 0.014161,\n"
             "                           0.565380, 78.216336, 1.675299, 430.230564),",
             "Crystal(11, (0.665721, 0.0036, 0.503511, 0.011236, 0.214792, 0.014161,\n"
             "                           0.539173, 77.299264, 1.807613, 388.09),", QUARTZ),
    Mutation("quartz_use_silent", "QUARTZ used without the located note naming it a substitute",
             "deeplens/optics/io/zmx_glass.py",
             '                 "BIREFRINGENT": birefringent_note}', "}", QUARTZ),
    # branch gcode: a six-digit n_d/V_d glass code read as a model glass (glass_codes="model")
    Mutation("glass_code_split_4_2", "a six-digit glass code split after four digits (847238 "
             "read as n_d 1.8472, V_d 38) instead of NNN/VVV (n_d 1.847, V_d 23.8)",
             "deeplens/optics/io/zmx_glass_codes.py",
             'tok = f"{g[:3]}.{g[3:]}"', 'tok = f"{g[:4]}.{g[4:]}"',
             ("tests/optics/io/test_zmx_glass_codes.py",)),
    # branch telecen: an entrance pupil at infinity the file does not flag, read telecentric
    Mutation("telecentric_pupil_cone_from_first_vertex", "the cone of a telecentric lens whose "
             "entrance pupil is at infinity sized as if its pupil plane were the first vertex "
             "(the stop's radius no longer f tan(asin NA))",
             "deeplens/optics/paraxial.py", "ya_s = (s * ya_s + yb_s) / L",
             "ya_s = (s * ya_s + yb_s) / s",
             ("tests/optics/io/test_zmx_pupil_at_infinity.py",)),
    # ---------------------------------------- issue 37: the pivot after a flat mirror (pivot2)
    Mutation("pivot_after_mirror_read_as_virtual", "after a flat mirror, a surface turned about a "
             "pivot (its vertex ahead of the beam) read as virtual propagation: a backward gap "
             "and a note that says the rays go back",
             "deeplens/optics/io/zmx_read.py",
             "if ahead is not None and ahead[1] > 0:\n            lens.backward_gaps",
             "if ahead is not None and ahead[1] > 1e30:\n            lens.backward_gaps",
             ("tests/optics/io/test_zmx_pivot.py",)),
    # ------------------- issue 37: OpticStudio's sample lenslet array US_ARRAY.DLL (branch usarray)
    Mutation("lenslet_corner_on_vertex", "an odd lenslet array laid out with a corner on the "
             "vertex (the centres shifted by half a width: the layout OpticStudio's stored "
             "semi-diameters rule out)",
             "deeplens/optics/surfaces/lenslet_array.py",
             "        return (i + 0.5 - 0.5 * n) * w, s\n",
             "        return (i - 0.5 * n) * w, s\n",
             ("tests/optics/io/test_zmx_lenslet_array.py",)),
    Mutation("lenslet_array_capped_at_one_lenslet", "a lenslet array's automatic semi-diameter "
             "capped at one lenslet's sphere (0.999 |R|) instead of the array's extent",
             "deeplens/optics/io/zmx_read.py",
             '    own = getattr(surf, "domain_radius", None)\n',
             "    own = None\n",
             ("tests/optics/io/test_zmx_lenslet_array.py",)),
    # branch catalogs (issue 37 item 2): SCHOTT's IRG glasses under OpticStudio's SCHOTT_IRG
    Mutation("shelf_irg_constant_dropped", "the constant c0 of SCHOTT's IRG Sellmeier formula "
             "(n² = 1 + c0 + ...) dropped in the mapping onto AGF formula 2",
             "deeplens/optics/io/shelf_glass.py", "pairs.insert(0, (c[0], 0.0))",
             "pairs.insert(0, (0.0, 0.0))", ("tests/optics/io/test_shelf_glass.py",)),
    Mutation("shelf_irg_formula1_pole_unsquared", "a refractiveindex.info formula 1 entry's "
             "poles taken as C instead of C² (IRG23)", "deeplens/optics/io/shelf_glass.py",
             'pairs = [(c[i], c[i + 1] ** 2 if kind == "formula 1" else c[i + 1])',
             "pairs = [(c[i], c[i + 1])", ("tests/optics/io/test_shelf_glass.py",)),
    Mutation("shelf_irg_use_silent", "a SCHOTT_IRG glass used without the located note naming "
             "its flyer and how far OpticStudio's catalogue lies", "deeplens/optics/io/zmx_glass.py",
             "_SOURCE_NOTES |= {c: (lambda g, c=c: shelf_note(g, c)) for c in SHELF_CATALOGUES}",
             "", ("tests/optics/io/test_shelf_glass.py",)),
    Mutation("ir_glass_written_nd_one", "a catalogue glass with no index at the d line written "
             "with n_d 1, V_d 0 instead of OpticStudio's 1.5/40 placeholder",
             "deeplens/optics/io/zmx_write.py",
             'nd_vd = f"{_f(_PLACEHOLDER_ND_VD[0])} {_f(_PLACEHOLDER_ND_VD[1])}"',
             'nd_vd = "1.0 0.0"', ("tests/optics/io/test_shelf_glass.py",)),
    # branch xosphere: OpticStudio's Extended Odd Asphere (XOSPHERE), XDAT i + 2 on ρ^i
    Mutation("xosphere_term_index_off_by_one", "an Extended Odd Asphere's coefficient A_i read "
             "onto ρ^(i+1) (XDAT 3 taken as the ρ² term, as the Extended Asphere's)",
             "deeplens/optics/io/zmx_xosphere.py",
             "terms = [s.xdat.get(i + 2, (0.0, s.type_line)) for i in range(1, n + 1)]",
             "terms = [s.xdat.get(i + 1, (0.0, s.type_line)) for i in range(1, n + 1)]",
             ("tests/optics/io/test_zmx_xosphere.py",)),
    Mutation("extended_odd_asphere_rho_power_off_by_one", "the Extended Odd Asphere's terms "
             "evaluated at ρ = r / R_n² in the sag (not r / R_n; the slopes left right)",
             "deeplens/optics/surfaces/extended_odd_asphere.py",
             "        sigma = s / self.norm_radius.to(s) ** 2\n",
             "        sigma = s / self.norm_radius.to(s) ** 4\n",
             ("tests/optics/surfaces/test_extended_odd_asphere.py",)),
    # branch misc: OpticStudio materials deeplens ships as named stand-ins (MISC ACRYLIC,
    # POLYSTYR; ZEON E48R) and INFRARED's F_SILICA
    Mutation("standin_use_silent", "a named stand-in (ACRYLIC, POLYSTYR, E48R) used without "
             "the located warning that names it and its source",
             "deeplens/optics/io/zmx_glass.py",
             "        p.note(s.glass_line, standin_note(name, cat, s.glass_model))\n",
             "        pass\n", ("tests/optics/io/test_standin_glass.py",)),
    Mutation("standin_nd_never_checked", "a GLAS line whose own n_d lies beyond what the "
             "stand-in is trusted to loads with the stand-in instead of being refused",
             "deeplens/optics/io/standin_glass.py",
             "    if abs(nd_file - nd) <= STANDIN_ND_TOL:\n", "    if True:\n",
             ("tests/optics/io/test_standin_glass.py",)),
    # branch setups12: an image-space F-number on a negative focal length (EPD = |EFL| / F#)
    Mutation("fno_epd_signed_efl", "the pupil of an image-space F-number taken from the signed "
             "EFL (EPD = EFL / F#: a negative pupil on a relay with one intermediate image)",
             "deeplens/optics/paraxial.py", "    return abs(efl) / fno\n",
             "    return efl / fno\n", ("tests/optics/io/test_zmx_set12_rules.py",)),
    Mutation("range_refusal_previous_unnamed", "a wavelength refused beyond a previous "
             "(Robb & Mercado, visible-only) glass's range named as if from the current "
             "catalogue (why the range is 400-700 nm lost)",
             "deeplens/optics/io/zmx_glass.py",
             "             if isinstance(m, BuchdahlGlass) else f\"catalogue {cat}\")",
             "             if False else f\"catalogue {cat}\")",
             ("tests/optics/io/test_zmx_set12_rules.py",)),
    Mutation("image_before_vertex_beam_backwards", "an image plane before the last vertex after "
             "a curved mirror said to be reached forwards where the beam leaves away from it "
             "(a slip of sign named an off-axis section, and the other way round)",
             "deeplens/optics/io/zmx_read.py",
             "    if bool(ok[0]) and bool((t[ok] > 0).all()):\n",
             "    if bool(ok[0]) and bool((t[ok] < 0).all()):\n",
             ("tests/optics/io/test_zmx_set12_rules.py",)),
    Mutation("curved_image_clears_somewhere", "a curved image surface said to clear the last "
             "surface where it clears it at some radius, not at every one",
             "deeplens/optics/io/zmx_read.py",
             "    clears = bool((torch.nan_to_num(gap, nan=1.0) >= -1e-9).all())\n",
             "    clears = bool((torch.nan_to_num(gap, nan=1.0) >= -1e-9).any())\n",
             ("tests/optics/io/test_zmx_set12_rules.py",)),
    # branch warnone: one located warning per cause, naming its lines, not one per line
    Mutation("warnings_per_line_again", "the notes of one cause (three GLAS lines read from "
             "six-digit codes) issued as one warning per line again, not one naming every line",
             "deeplens/optics/io/zmx_parse.py",
             'g = groups.setdefault(("cause", cause) if cause else ("text", msg), [[], {}, cause])',
             'g = groups.setdefault(("note", i), [[], {}, cause])',
             ("tests/optics/io/test_zmx_warning_groups.py",)),
    # branch warnone: the shared refusal of PARM/XDAT records a surface type does not read
    Mutation("unread_negative_value_accepted", "a negative PARM/XDAT value a surface type does "
             "not read silently dropped (only positive ones refused)",
             "deeplens/optics/io/surface_formats.py", "if i not in read and v != 0:",
             "if i not in read and v > 0:", ("tests/optics/io/test_zmx_unread_records.py",)),
    # branch ftyp3: set 12's real image heights (FTYP 3) on wide-angle camera lenses
    Mutation("quadric_vertex_plane_domain_check", "a ray whose vertex-plane point lies outside a "
             "sphere's domain marked invalid again (the chief ray of a 28 mm lens's edge field "
             "lost at a rear surface it does meet)", "deeplens/optics/intersect.py",
             "            t0 = torch.where(surface.in_domain(xy0[..., 0], xy0[..., 1]), t0,\n"
             "                             -(o * d).sum(-1))\n",
             "            ok = ok & surface.in_domain(xy0[..., 0], xy0[..., 1])\n",
             ("tests/optics/test_quadric_beyond_domain.py",)),
    Mutation("quadric_beyond_domain_from_origin", "a ray whose vertex-plane point lies outside "
             "a conic's domain solved from its origin (float32 loses the hit's digits to |o|^2 "
             "when the origin lies far away) instead of the line's point nearest the vertex",
             "deeplens/optics/intersect.py",
             "        tc = -(ox * dx + oy * dy + oz * dz)\n",
             "        tc = torch.zeros_like(t0)\n",
             ("tests/optics/test_quadric_beyond_domain.py",)),
    Mutation("ftyp3_provisional_semi_diameters_clip", "automatic semi-diameters left at their "
             "provisional 1e-3 mm while FTYP 3 chief rays are solved (the aimed chief ray stopped "
             "by a plane OpticStudio never clips)", "deeplens/optics/io/zmx_read.py",
             "    with _unsized(lens, autos):", "    with _unsized(lens, []):", LENS2_FTYP3),
    Mutation("chief_ray_stop_tir_called_miss", "an FTYP 3 refusal that says the chief ray misses "
             "a surface where it is totally reflected there", "deeplens/optics/io/zmx_system.py",
             'return i, "is totally reflected at"', 'return i, "misses"', LENS2_FTYP3),
    Mutation("sideways_fields_read_radially", "a field angle beyond 90 deg (a fisheye's 109 deg) "
             "passed to the radial x-y combination, which reads it as 71 deg without a word",
             "deeplens/optics/io/zmx_system.py",
             "    if kind == 0:\n        xs, ys = _drop_sideways_fields(",
             "    if kind == -1:\n        xs, ys = _drop_sideways_fields(",
             ("tests/optics/io/test_zmx_sideways_fields.py",)),
    # ---------------------------------------------- issue 37: session-17 review (numbers kept)
    Mutation("grouped_note_drops_numbers", "the one warning of several PARAX_XY surfaces lists "
             "the surfaces without their x and y powers",
             "deeplens/optics/io/surface_handlers.py",
             'f"SURF {k}: {px:.6g} / {py:.6g} /mm")', 'None)',
             ("tests/optics/io/test_zmx_warning_groups.py",)),
    # branch setups13: set 13's set-up rules
    Mutation("drawn_dummy_gap_merged_backwards", "the gap of a drawn-only focal-plane dummy "
             "dropped after the image plane merged with the wrong sign (the sensor 2 delta past "
             "the focus)", "deeplens/optics/io/zmx_read.py",
             "    seq.gap = last[3] + seq.gap\n", "    seq.gap = last[3] - seq.gap\n",
             ("tests/optics/io/test_zmx_set13_rules.py",)),
    Mutation("fno_pupil_at_infinity_afocal_swapped", "an image-space F-number on an entrance "
             "pupil at infinity refused as afocal where the EFL is finite, and the reverse",
             "deeplens/optics/io/zmx_read.py",
             "is inf/inf and sets no cone\" if math.isinf(efl) else",
             "is inf/inf and sets no cone\" if not math.isinf(efl) else",
             ("tests/optics/io/test_zmx_set13_rules.py",)),
    Mutation("beyond_90_estimate_wrong_sign", "the FTYP 3 refusal's estimate of the angle that "
             "would reach the height stepping the wrong way from the last angle found",
             "deeplens/optics/io/zmx_system.py", "    est = lo - glo / slope\n",
             "    est = lo + glo / slope\n", ("tests/optics/io/test_zmx_set13_rules.py",)),
    Mutation("fixed_diam_beyond_edge_kept", "a fixed DIAM beyond the edge of its sphere kept as "
             "written (the lens refused again) instead of read at the edge",
             "deeplens/optics/io/zmx_surfaces.py",
             "        surf.semi_diameter.fill_(edge)\n", "        surf.semi_diameter.fill_(sd)\n",
             ("tests/optics/io/test_zmx_set13_rules.py",)),
]

def run_pytest(copy: Path, tests, timeout: float) -> tuple[int, float, str]:
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    t0 = time.time()
    try:
        p = subprocess.run(cmd, cwd=copy, env=env, capture_output=True, text=True,
                           timeout=timeout)
        rc, out = p.returncode, p.stdout + p.stderr
    except subprocess.TimeoutExpired:
        rc, out = -1, "timeout"
    first = [line for line in out.splitlines() if line.startswith(("FAILED", "ERROR"))]
    last = out.strip().splitlines()[-1:] or [""]
    return rc, time.time() - t0, (first or last)[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="run the default suite for every bug")
    ap.add_argument("--only", action="append", default=[], help="run only these mutations")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    args = ap.parse_args(argv)
    muts = [m for m in MUTATIONS if not args.only or m.name in args.only]
    if args.only and len(muts) != len(set(args.only)):
        known = {m.name for m in MUTATIONS}
        ap.error(f"unknown mutation(s): {sorted(set(args.only) - known)}")
    if args.list:
        for m in muts:
            print(f"{m.name:32s} {m.file:40s} {m.what}")
        return 0
    with tempfile.TemporaryDirectory(prefix="deeplens-mutants-") as tmp:
        copy = Path(tmp) / "repo"
        shutil.copytree(ROOT, copy, ignore=IGNORE)
        suites = {("tests",)} if args.full else {m.tests for m in muts}
        for tests in sorted(suites):
            rc, dt, last = run_pytest(copy, tests, args.timeout)
            if rc != 0:
                print(f"the unmutated copy fails {' '.join(tests)} ({last}); fix that first")
                return 2
        rows, bad = [], 0
        for k, m in enumerate(muts, 1):
            path = copy / m.file
            text = path.read_text()
            tests = ("tests",) if args.full else m.tests
            if m.old not in text:
                result, dt, detail = "STALE (text not found)", 0.0, ""
                bad += 1
            else:
                path.write_text(text.replace(m.old, m.new))
                try:
                    rc, dt, detail = run_pytest(copy, tests, args.timeout)
                finally:
                    path.write_text(text)
                result = "caught" if rc != 0 else "**MISSED**"
                bad += rc == 0
            rows.append((k, m, result, dt, " ".join(tests), detail))
            print(f"[{k}/{len(muts)}] {m.name}: {result} ({dt:.0f} s)", file=sys.stderr,
                  flush=True)
    print("| # | planted bug | file | issue 13 | tests run | result | first failure | s |")
    print("|---|---|---|---|---|---|---|---|")
    for k, m, result, dt, tests, detail in rows:
        detail = detail.replace("|", "\\|")[:90]
        print(f"| {k} | {m.what} (`{m.name}`) | `{m.file}` | {'yes' if m.issue else ''} | "
              f"`{tests}` | {result} | {detail} | {dt:.0f} |")
    caught = sum(r[2] == "caught" for r in rows)
    print(f"\n{caught} of {len(rows)} planted bugs caught.")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
