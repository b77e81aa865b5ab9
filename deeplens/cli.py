"""Command line: ``deeplens report|plot|optimize|tolerance|render|lenses|design|train|eval ...``
(``deeplens -h``, ``deeplens --version``)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

__all__ = ["main"]


class _UsageError(ValueError):
    """A bad command-line value (exit status 2, like argparse's own errors)."""


def _missing(cmd: str, extra: str, modules=None) -> bool:
    """Print one line naming the extra to install and return ``True`` when a module ``cmd``
    needs is missing (:mod:`deeplens.extras`); checked before any work (loading, tracing)."""
    from .extras import missing_extra

    msg = missing_extra(extra, f"deeplens {cmd}", modules)
    if msg:
        print(f"deeplens {cmd}: error: {msg}", file=sys.stderr)
    return msg is not None


def _floats(text: str, what: str, unit: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise _UsageError(f"{what} must be comma-separated numbers in {unit}, got "
                          f"{text!r}") from None
    if not values:
        raise _UsageError(f"{what}: no values given ({text!r})")
    if not all(math.isfinite(v) for v in values):
        raise _UsageError(f"{what} must be finite numbers, got {text!r}")
    return values


def _add_sampling_option(parser, what: str = "") -> None:
    """``--sampling``, with the one default of every RMS spot the command line prints."""
    from .optics.sampling import DEFAULT_SAMPLING

    parser.add_argument("--sampling", default=DEFAULT_SAMPLING,
                        help=f"pupil sampling{what}: hexapolar:RINGS, grid:N or random:N[:SEED] "
                             f"(default %(default)s, the same in report, plot, optimize and "
                             f"tolerance, so one lens has one RMS)")


def _shipped_names() -> list[str]:
    from .resources import lens_dir

    return sorted(q.stem for q in lens_dir().glob("*.json"))


def _lens_help() -> str:
    return (f"lens file (.json, the paper authors' .txt table, Zemax .zmx, CODE V .seq) or a "
            f"shipped lens: {', '.join(_shipped_names())} (deeplens lenses: one line each)")


def _elements(lens) -> int:
    """Glass (or any non-air) media between surfaces: the elements, a cemented pair counting
    two."""
    from .optics.materials import Air

    return sum(not isinstance(m, Air) for m in list(lens.materials)[1:])


def _lenses(args) -> int:
    """``deeplens lenses``: the shipped lenses, one line each (EFL, F/#, elements, what)."""
    import torch

    from .optics.io import load_lens
    from .optics.paraxial import paraxial
    from .resources import lens_dir

    rows = []
    for name in _shipped_names():
        lens = load_lens(lens_dir() / f"{name}.json").to(torch.float64)
        p = paraxial(lens)
        what = lens.name.split(" (")[0]
        rows.append({"name": name, "efl_mm": float(p.efl), "fno": float(p.fno),
                     "elements": _elements(lens), "description": lens.name})
        rows[-1]["_short"] = what if len(what) <= 60 else what[:57] + "..."
    if args.json:
        print(json.dumps([{k: v for k, v in r.items() if k != "_short"} for r in rows],
                         indent=1))
        return 0
    w = max(len(r["name"]) for r in rows)
    print(f"{'name':<{w}}  {'EFL (mm)':>9}  {'F/#':>5}  {'elements':>8}  what")
    for r in rows:
        print(f"{r['name']:<{w}}  {r['efl_mm']:>9.2f}  {r['fno']:>5.2f}  {r['elements']:>8d}  "
              f"{r['_short']}")
    print(f"(a name works wherever a lens file does: deeplens report {rows[0]['name']}; files "
          f"in {lens_dir()})")
    return 0


def _add_lens_options(parser) -> None:
    """The reader options of the paper authors' ``.txt`` tables (they carry no stop row)."""
    g = parser.add_argument_group("table files (.txt)")
    g.add_argument("--stop-index", type=int, metavar="I",
                   help="surface index (0-based, the rows after O) whose clear aperture is the "
                        "stop, for a table without an A row (e.g. 0 for ACL5040U, LA1131, "
                        "end2end_edof)")
    g.add_argument("--scale", type=float, metavar="S",
                   help="multiply every length of the table by S (e.g. 10 for the Nikon patent "
                        "table in normalised units)")
    z = parser.add_argument_group("Zemax files (.zmx)")
    z.add_argument("--glass-catalog", action="append", metavar="PATH", dest="glass_catalog",
                   help="a glass catalogue (.agf) to look glasses up in, answering for the GCAT "
                        "name equal to its file stem (repeatable; also the DEEPLENS_GLASS_PATH "
                        "environment variable: .agf files and folders, separated by "
                        f"{os.pathsep!r})")
    z.add_argument("--qbfs-conic", choices=("forbes", "refuse"), dest="qbfs_conic",
                   help="a QED_TYPE Qbfs surface on a conic base, which no OpticStudio page "
                        "defines: 'forbes' (default) reads it with Forbes' conic "
                        "generalisation (as optiland) and a located warning, 'refuse' refuses "
                        "it at its line")
    z.add_argument("--stop-size", choices=("limiting", "refuse"), dest="stop_size",
                   help="a stop with no semi-diameter under FLOA (float by stop size), which "
                        "the file alone does not size: 'limiting' (default) floats it to the "
                        "largest on-axis beam the other surfaces' fixed apertures pass, with a "
                        "located warning, 'refuse' refuses it at its line")
    z.add_argument("--glass-codes", choices=("refuse", "model"), dest="glass_codes",
                   help="a GLAS name that is a six-digit n_d/V_d code (847238: n_d 1.847, V_d "
                        "23.8) and in no catalogue, which OpticStudio's catalogues do not hold: "
                        "'refuse' (default) refuses it at its line, 'model' reads it as that "
                        "model glass with a located warning")
    try:     # optimize has its own -v (every trial step); it shows these details too
        z.add_argument("-v", "--verbose", action="store_true",
                       help="with an error, print its details too (e.g. every glass catalogue "
                            "searched)")
    except argparse.ArgumentError:
        pass


def _zmx_only(lens: str, flag: str) -> None:
    """Refuse ``flag``, an option of the Zemax reader, for a lens file that is not ``.zmx``."""
    from pathlib import Path

    if Path(lens).suffix.lower() != ".zmx":
        raise _UsageError(f"{flag} applies to Zemax files (.zmx) only; {lens} is not one")


def _load(args):
    """``load_lens(args.lens)`` with the table options given on the command line."""
    from pathlib import Path

    from .optics.errors import LensFileError
    from .optics.io import load_lens

    opts = {k: v for k, v in (("stop_index", getattr(args, "stop_index", None)),
                              ("scale", getattr(args, "scale", None))) if v is not None}
    if opts and Path(args.lens).suffix.lower() != ".txt":
        flags = ", ".join("--" + k.replace("_", "-") for k in opts)
        raise _UsageError(f"{flags} apply to the paper authors' .txt tables only; "
                          f"{args.lens} is not one")
    catalogs = getattr(args, "glass_catalog", None)
    if catalogs:
        _zmx_only(args.lens, "--glass-catalog")
        missing = [c for c in catalogs if not Path(c).is_file()]
        if missing:
            raise _UsageError(f"--glass-catalog: no such file: {missing[0]}")
        opts["glass_catalogs"] = list(catalogs)
    for key in ("qbfs_conic", "stop_size", "glass_codes"):      # read_zmx's reading rules, by name
        value = getattr(args, key, None)
        if value is not None:
            _zmx_only(args.lens, "--" + key.replace("_", "-"))
            opts[key] = value
    config = getattr(args, "config", None)
    if config is not None:
        if Path(args.lens).suffix.lower() not in (".zmx", ".seq"):
            raise _UsageError(f"--config applies to Zemax files (.zmx) and CODE V zoom lenses "
                              f"(.seq) only; {args.lens} is neither")
        opts["config"] = config
    try:
        return load_lens(args.lens, **opts)
    except LensFileError as e:
        if e.key == "stop_index" and "stop_index" not in opts:
            raise _UsageError(f"{e}; on the command line: --stop-index I (e.g. --stop-index 0 "
                              f"for the first surface)") from None
        details = getattr(e, "details", None)
        if details:     # one line; the details with -v
            e.args = (f"{e}\n  {details}" if getattr(args, "verbose", False)
                      else f"{e} (-v: details)",)
        raise


def _report(args) -> int:
    import torch

    from .analysis.checks import AnalysisError, check_wavelength
    from .analysis.report import analysis_report, format_report, lens_report
    from .optics.io.zmx import lens_pupil_convention
    from .optics.materials import check_wavelength_nm
    from .optics.sampling import parse_sampling

    try:
        parse_sampling(args.sampling)
        fields = waves = None
        if args.fields is not None:
            fields = _floats(args.fields, "--fields", "degrees (e.g. 0,7,14)")
            if not all(abs(f) < 90 for f in fields):
                raise _UsageError(f"--fields: field angles are in degrees and must lie within "
                                  f"(-90, 90), got {args.fields!r}")
        if args.wavelengths is not None:
            waves = _floats(args.wavelengths, "--wavelengths", "nm (e.g. 486.1,587.6)")
        if waves:
            check_wavelength_nm(waves, where="--wavelengths: ")
        lens = _load(args).to(torch.float64)
        if waves:
            try:
                check_wavelength(lens, waves, owner=f" of {args.lens}")
            except AnalysisError as e:
                raise _UsageError(f"--wavelengths: {e}") from None
        kinds = _analysis_kinds(args.analysis) if args.analysis is not None else None
        pupil = args.pupil or lens_pupil_convention(lens)   # a .zmx file's RAIM decides
        rep = lens_report(lens, fields, waves, args.sampling, pupil, args.image_plane)
        if kinds:
            rep["analysis"] = analysis_report(lens, kinds, fields, waves, args.image_plane)
    except (ValueError, OSError) as e:
        print(f"deeplens report: error: {e}", file=sys.stderr)
        return 2
    text = json.dumps(rep, indent=1) if args.json else format_report(rep)
    if not args.json and "analysis" in rep:
        from .analysis.report import format_analysis

        text += "\n\n" + format_analysis(rep["analysis"])
    print(text)
    return 0


def _analysis_kinds(text: str) -> list[str]:
    """``report --analysis KIND,...``: the kinds, checked before any tracing."""
    from .analysis.report import ANALYSES

    kinds = [k.strip() for k in text.split(",") if k.strip()]
    if not kinds:
        raise _UsageError(f"--analysis: no kinds given ({text!r})")
    bad = [k for k in kinds if k not in ANALYSES]
    if bad:
        raise _UsageError(f"--analysis: unknown kind(s) {', '.join(bad)}; choose from "
                          f"{','.join(ANALYSES)}")
    return kinds


def _plot(args) -> int:
    """``deeplens plot LENS --kind KIND [--fields] [--wavelengths] -o OUT.png``."""
    if _missing("plot", "plot", ("matplotlib",)):
        return 2
    import torch

    from .analysis.plot import plot
    from .optics.sampling import parse_sampling

    try:
        fields, waves = _fields_waves(args)
        freqs = None
        if args.freqs is not None:
            freqs = _floats(args.freqs, "--freqs", "cycles/mm (e.g. 10,30,50)")
            if any(f < 0 for f in freqs):
                raise _UsageError(f"--freqs must be >= 0 cycles/mm, got {args.freqs!r}")
        if args.dpi is not None and not args.dpi > 0:
            raise _UsageError(f"--dpi must be > 0, got {args.dpi}")
        parse_sampling(args.sampling)
        lens = _load(args).to(torch.float64)
        plot(lens, args.kind, args.output, fields, waves, image_plane=args.image_plane,
             dpi=args.dpi, freqs=freqs, sampling=args.sampling)
    except (ValueError, OSError) as e:
        print(f"deeplens plot: error: {e}", file=sys.stderr)
        return 2
    print(args.output)
    return 0


def _add_plot_parser(sub) -> None:
    from .analysis.plot import KINDS

    q = sub.add_parser("plot", help="draw an analysis figure of a lens file (PNG, PDF, SVG)")
    q.add_argument("lens", help=_lens_help())
    q.add_argument("--kind", required=True, choices=list(KINDS),
                   help="which figure (mtf: polychromatic over --wavelengths; through-focus: MTF "
                        "vs focus shift; mtf-field: MTF vs field angle)")
    q.add_argument("--fields", help="field angles in degrees, e.g. 0,7,14,21 (default: file's)")
    q.add_argument("--wavelengths", help="wavelengths in nm, e.g. 486.1,587.6 (default: "
                                         "file's; the first is used for monochromatic plots)")
    q.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    q.add_argument("-o", "--output", required=True,
                   help="output file; the suffix picks the format: .pdf, .svg, .eps (vector) or "
                        ".png, .jpg, .tif (raster)")
    q.add_argument("--dpi", type=float, help="resolution of raster output (default 150)")
    q.add_argument("--freqs", help="frequencies in cycles/mm for --kind through-focus and "
                                   "mtf-field, e.g. 10,30,50 (default ~10/25/50 %% of the "
                                   "cut-off)")
    _add_sampling_option(q, " of --kind spot")
    _add_lens_options(q)
    q.set_defaults(func=_plot)
def _fields_waves(args):
    from .optics.materials import check_wavelength_nm

    fields = waves = None
    if getattr(args, "fields", None) is not None:
        fields = _floats(args.fields, "--fields", "degrees (e.g. 0,7,14)")
        if not all(abs(f) < 90 for f in fields):
            raise _UsageError(f"--fields: field angles are in degrees and must lie within "
                              f"(-90, 90), got {args.fields!r}")
    if getattr(args, "wavelengths", None) is not None:
        waves = _floats(args.wavelengths, "--wavelengths", "nm (e.g. 486.1,587.6)")
        check_wavelength_nm(waves, where="--wavelengths: ")
    return fields, waves


def _rms_table(fields, waves, before, after=None) -> str:
    head = f"  {'field (deg)':>11} {'lambda (nm)':>11} {'RMS before (um)':>16}"
    lines = [head + (f" {'RMS after (um)':>15}" if after is not None else "")]
    for i, f in enumerate(fields):
        for j, w in enumerate(waves):
            row = f"  {f:>11.4g} {w:>11.6g} {before[i][j]:>16.4f}"
            if after is not None:
                row += f" {after[i][j]:>15.4f}"
            lines.append(row)
    return "\n".join(lines)


def _optimize(args) -> int:
    from pathlib import Path

    import torch

    from .design.constraints import parse_constraint
    from .design.lensopt import optimize_lens
    from .design.merit import Merit, SpotMerit
    from .design.variables import Variables
    from .optics.io import save_lens
    from .optics.sampling import parse_sampling

    try:
        parse_sampling(args.sampling)
        if args.steps < 1:
            raise _UsageError(f"--steps must be >= 1, got {args.steps}")
        fields, waves = _fields_waves(args)
        out = Path(args.out)
        if out.suffix.lower() != ".json":
            raise _UsageError(f"--out must name a .json lens file, got {args.out!r}")
        if not out.parent.exists():
            raise _UsageError(f"--out: folder {str(out.parent)!r} does not exist")
        lens = _load(args).to(torch.float64)
        variables = Variables(lens, args.vary)
        constraints = [c for text in args.constraint or [] for c in parse_constraint(lens, text)]

        def report_merit():
            return SpotMerit(fields, waves, sampling=args.sampling, image_plane=args.image_plane,
                             shrink=1.0, per_wavelength_pupil=True, strict_rays=False)

        rep = report_merit().prepare(lens)
        with torch.no_grad():
            rms_before = (rep.rms(lens) * 1e3).tolist()
        focus = _refocus(lens, args, fields, waves)
        merit = Merit(SpotMerit(fields, waves, sampling=args.sampling,
                                reference=args.reference, image_plane=args.image_plane,
                                strict_rays=not args.allow_vignetting))
        res = optimize_lens(lens, variables, merit, method=args.method, steps=args.steps,
                            constraints=constraints, rounds=args.rounds,
                            jacobian_mode=args.jacobian)
        rep = report_merit().prepare(lens)
        with torch.no_grad():
            rms_after = (rep.rms(lens) * 1e3).tolist()
        # written only now (nothing if anything above failed), atomically, mode from the umask
        save_lens(lens, out)
    except (ValueError, OSError) as e:
        print(f"deeplens optimize: error: {e}", file=sys.stderr)
        return 2
    result = {"merit_before": res.merit_before, "merit_after": res.merit_after,
              "rms_before_um": [x for row in rms_before for x in row],
              "rms_after_um": [x for row in rms_after for x in row],
              "fields_deg": rep.fields, "wavelengths_nm": rep.waves,
              "seconds": res.seconds, "steps": res.steps, "method": args.method,
              "evaluations": sum(r.evaluations for r in res.rounds),
              "stop_reason": res.reason, "variables_before": res.variables_before,
              "variables_after": res.variables_after, "out": str(out),
              "accepted_steps": res.accepted, "rejected_steps": res.rejected,
              "rejections": [{"reason": r, "count": n} for r, n in res.rejections()],
              "allow_vignetting": bool(args.allow_vignetting), "refocus": focus}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        if focus is not None and focus["applied"]:
            print(f"Quick focus first: sensor {focus['d_sensor_before_mm']:.6g} -> "
                  f"{focus['d_sensor_after_mm']:.6g} mm (RMS {focus['rms_before_um']:.4g} -> "
                  f"{focus['rms_after_um']:.4g} um)")
        print(f"Optimised {len(variables)} variable(s) of {args.lens} by {args.method}: merit "
              f"{res.merit_before:.6g} -> {res.merit_after:.6g} mm^2 in {res.steps} steps, "
              f"{res.seconds:.2f} s ({res.reason})")
        if args.verbose:
            print(_step_log(res))
        print(_steps_summary(res, args.allow_vignetting))
        print(_rms_table(rep.fields, rep.waves, rms_before, rms_after))
        print(f"wrote {out}")
    return 0


def _refocus(lens, args, fields, waves):
    """``--refocus``: quick focus (:mod:`deeplens.design.focus`) before optimising; ``auto``
    moves the sensor only when that at least halves the RMS spot (the start is far out of
    focus).  Returns a JSON-able record, or ``None`` when not tried."""
    if args.refocus == "never" or args.image_plane != "sensor":
        return None
    from .design.focus import quick_focus

    f = quick_focus(lens, fields, waves, sampling=args.sampling, apply=False)
    apply = args.refocus == "always" or f.rms_after_mm <= 0.5 * f.rms_before_mm
    if apply:
        quick_focus(lens, fields, waves, sampling=args.sampling)
    return {"applied": apply, "mode": args.refocus, "shift_mm": f.shift_mm,
            "d_sensor_before_mm": f.d_sensor_before, "d_sensor_after_mm": f.d_sensor_after,
            "rms_before_um": f.rms_before_mm * 1e3, "rms_after_um": f.rms_after_mm * 1e3}


def _step_log(res) -> str:
    """``optimize --verbose``: each trial in order, accepted or rejected with its reason."""
    lines = []
    for h in res.history:
        if h["step"] == 0:
            continue
        lines.append(f"  step {h['step']}: " + (f"accepted, merit {h['merit']:.6g} mm^2"
                                                if h["accepted"] else
                                                f"rejected: {h.get('reason', '')}"))
    return "\n".join(lines)


def _steps_summary(res, allow_vignetting: bool) -> str:
    """``steps: A accepted, R rejected`` and each distinct rejection reason with its count."""
    lines = [f"steps: {res.accepted} accepted, {res.rejected} rejected"]
    for reason, n in res.rejections():
        lines.append(f"  rejected {n}x: {reason}")
    if not allow_vignetting and any(k == "vignetted" for k, _ in res.rejection_kinds()):
        lines.append("  (trial steps that vignette a ray are rejected; --allow-vignetting lets "
                     "the merit drop such rays instead)")
    return "\n".join(lines)


def _render(args) -> int:
    """``deeplens render LENS IMAGE --depth MM -o OUT.png``: the picture through the lens."""
    if _missing("render", "plot", ("PIL",)):     # Pillow reads and writes the pictures
        return 2
    import torch

    from .render.image import default_pixel_size, read_image, render_image, write_image
    from .render.sensor import RGB_WAVELENGTHS_NM

    try:
        if not (math.isfinite(args.depth) and args.depth > 0):
            raise _UsageError(f"--depth is the distance in mm from the first vertex to the "
                              f"picture and must be a finite number > 0, got {args.depth}")
        if args.spp < 1:
            raise _UsageError(f"--spp must be >= 1, got {args.spp}")
        if args.max_side < 2:
            raise _UsageError(f"--max-side must be >= 2 pixels, got {args.max_side}")
        pitch = None
        if args.pixel_size_um is not None:
            if not args.pixel_size_um > 0:
                raise _UsageError(f"--pixel-size-um must be > 0, got {args.pixel_size_um}")
            pitch = args.pixel_size_um * 1e-3
        focus = _focus_depth(args.focus, args.depth)
        lens = _load(args)
        img = read_image(args.image, max_side=args.max_side, linear=args.linear)
        H, W = img.shape[-2:]
        pitch = default_pixel_size(lens, (H, W)) if pitch is None else pitch
        d_file = float(lens.d_sensor)
        if focus is not None:
            from .training.lens_setup import best_focus_distance

            d = best_focus_distance(lens, min(focus, _FAR_MM), RGB_WAVELENGTHS_NM)
            with torch.no_grad():
                lens.d_sensor.fill_(d)
            lens.check()
        blur_um = _on_axis_blur_um(lens, args.depth, RGB_WAVELENGTHS_NM)
        out = render_image(lens, img, args.depth, pixel_size_mm=pitch, spp=args.spp,
                           seed=args.seed)
        path = write_image(out, args.output, linear=args.linear)
    except (ValueError, OSError) as e:
        print(f"deeplens render: error: {e}", file=sys.stderr)
        return 2
    print(path)
    print(f"  sensor: {W} x {H} pixels, {W * pitch:.4g} x {H * pitch:.4g} mm, pixel pitch "
          f"{pitch * 1e3:.4g} um")
    if focus is None:
        where = "as in the lens file (--focus file)"
    elif math.isinf(focus):
        where = "at infinity (--focus inf)"
    else:
        where = (f"at {focus:g} mm" + (" (the object depth; --focus to change)"
                                        if args.focus == "depth" else ""))
    print(f"  focus: {where}; sensor {float(lens.d_sensor):.5g} mm behind the last vertex "
          f"(lens file: {d_file:.5g} mm)")
    if blur_um is None:
        print(f"  blur: fewer than 3 on-axis rays from {args.depth:g} mm reach the sensor")
    else:
        print(f"  blur at {args.depth:g} mm: on-axis RMS spot diameter {blur_um:.3g} um = "
              f"{blur_um / (pitch * 1e3):.2g} pixels (R, G, B rays pooled)")
    return 0


def _focus_depth(text: str, depth: float) -> float | None:
    """``render --focus``: the distance (mm) to focus at, ``inf``, or ``None`` for the sensor
    where the lens file puts it (``file``); ``depth`` (the default) is the object depth."""
    t = text.strip().lower()
    if t == "depth":
        return depth
    if t == "file":
        return None
    if t in ("inf", "infinity"):
        return math.inf
    try:
        v = float(t)
    except ValueError:
        v = float("nan")
    if not (v > 0):
        raise _UsageError(f"--focus must be depth, file, inf or a distance in mm > 0, got "
                          f"{text!r}")
    return v


#: a point this far (mm) stands for infinity when focusing (the wavefront curvature it leaves,
#: ~EFL^2 / 1e8 mm of defocus, is far below any sensor pixel)
_FAR_MM = 1e8


def _on_axis_blur_um(lens, depth_mm: float, waves, n_rays: int = 4096) -> float | None:
    """Blur estimate of ``render``: the RMS spot diameter (um, twice the RMS radius about the
    centroid) of an on-axis point at ``depth_mm`` on the lens's sensor, the rays of
    ``waves`` pooled; ``None`` when fewer than 3 rays arrive."""
    import copy

    import torch

    from .optics.sampling import point_source_rays

    L = copy.deepcopy(lens).double()
    z_s = float(L.z_sensor())
    pts = []
    with torch.no_grad():
        for w in waves:
            out = L.trace(point_source_rays(L, (0.0, 0.0), depth_mm, float(w), n_rays, seed=0))
            o, d = out.o[out.valid], out.d[out.valid]
            pts.append(o[:, :2] + (z_s - o[:, 2:3]) * d[:, :2] / d[:, 2:3])
    p = torch.cat(pts)
    if p.shape[0] < 3:
        return None
    return 2e3 * float(((p - p.mean(0)) ** 2).sum(-1).mean().sqrt())


def _add_render_parser(sub) -> None:
    q = sub.add_parser("render", help="an image through the lens at a depth: the sensor image",
                       description="Place IMAGE as a plane DEPTH mm in front of the lens (filling "
                       "its field of view) and render what the sensor records, by backward "
                       "Monte Carlo ray tracing (R, G, B at 656.3, 587.6, 486.1 nm; relative "
                       "illumination included).  The sensor is moved to the best on-axis focus for "
                       "--focus (default: the picture's depth); the command prints the sensor "
                       "size, pixel pitch, focus and an estimate of the blur.")
    q.add_argument("lens", help=_lens_help())
    q.add_argument("image", help="picture file (PNG, JPEG, ...; sRGB)")
    q.add_argument("--depth", type=float, required=True,
                   help="object distance in mm from the first vertex (e.g. 2000)")
    q.add_argument("--focus", default="depth", metavar="MM|depth|inf|file",
                   help="where the sensor is focused: depth (default: at the picture, as a "
                        "camera focuses on its subject), a distance in mm, inf, or file (the "
                        "sensor where the lens file puts it, usually focused at infinity)")
    q.add_argument("-o", "--output", required=True, help="sensor image to write (.png, .jpg ...)")
    q.add_argument("--spp", type=int, default=16, help="rays per pixel per wavelength "
                                                      "(noise ~ 1/sqrt(spp); default 16)")
    q.add_argument("--max-side", type=int, default=512,
                   help="down-sample the picture so its longer side is at most this many pixels "
                        "(the sensor has the picture's resolution; default 512)")
    q.add_argument("--pixel-size-um", type=float,
                   help="pixel pitch in um (default: the sensor diagonal spans the lens file's "
                        "sensor size)")
    q.add_argument("--linear", action="store_true",
                   help="the files hold linear values (default: sRGB, decoded and re-encoded)")
    q.add_argument("--seed", type=int, default=0)
    _add_lens_options(q)
    q.set_defaults(func=_render)


def _tolerance(args) -> int:
    need = (("yaml",) if args.group else ()) + (("matplotlib",) if args.out else ())
    if need and _missing("tolerance", "plot", need):
        return 2
    from pathlib import Path

    import torch

    from .design.merit import SpotMerit
    from .design.sensitivity import rss_estimate, sensitivity_matrix
    from .design.tolerance import (load_tolerances, monte_carlo, monte_carlo_figure,
                                   resolve_tolerances)
    from .optics.sampling import parse_sampling

    try:
        parse_sampling(args.sampling)
        if args.monte_carlo < 0:
            raise _UsageError(f"--monte-carlo must be >= 0, got {args.monte_carlo}")
        fields, waves = _fields_waves(args)
        if args.tolerances and args.group:
            raise _UsageError("give --tolerances or --group, not both")
        spec = load_tolerances(args.tolerances) if args.tolerances else None
        lens = _load(args).to(torch.float64)
        waves = waves or [float(lens.spec.primary_wavelength_nm)]
        model = None
        if args.group:
            from .design.tolerance_groups import load_group

            model = load_group(args.group, where="--group")
            names, t = model.half_widths(lens)
        else:
            names, t = resolve_tolerances(lens, spec)
        if not names:
            raise _UsageError("no tolerance parameter has a non-zero tolerance")
        sm = SpotMerit(fields, waves, sampling=args.sampling, image_plane=args.image_plane,
                       strict_rays=False).prepare(lens)
        J = sensitivity_matrix(lens, sm, names)
        sig = t / 3 ** 0.5
        rss = rss_estimate(lens, sm, names, sig)
        result = {"lens": args.lens, "fields_deg": sm.fields, "wavelengths_nm": sm.waves,
                  "parameters": names, "half_widths": t.tolist(),
                  "distribution": ("uniform in +-half_width (sigma = half_width / sqrt 3)"
                                   if model is None else
                                   f"group {args.group} (RSS with sigma = half_width / sqrt 3 "
                                   f"= the group's std; Monte Carlo draws the group)"),
                  "nominal_um": rss["nominal_um"],
                  "sensitivity_um_per_unit": (J * 1e3).tolist(),
                  "rss_um": rss["rss_um"]}
        if args.monte_carlo:
            mc = monte_carlo(lens, sm, names, t, n=args.monte_carlo, seed=args.seed,
                             model=model)
            result["monte_carlo"] = {k: mc[k] for k in ("n", "seed", "percentiles_um",
                                                         "mean_um", "rms_um")}
            if args.out:
                Path(args.out).mkdir(parents=True, exist_ok=True)
                from .design.plots import save

                result["figure"] = save(monte_carlo_figure(mc, rss["rss_um"]),
                                        Path(args.out) / "monte_carlo.png")
    except (ValueError, OSError) as e:
        print(f"deeplens tolerance: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"Tolerances of {args.lens}: {len(names)} parameters, uniform in +-half-width")
    hdr = "  " + " ".join(f"{f:>10.4g}" for f in result["fields_deg"])
    print("  field (deg):" + hdr[2:])
    print("  nominal RMS (um):  " + " ".join(f"{x:10.4f}" for x in result["nominal_um"]))
    print("  RSS estimate (um): " + " ".join(f"{x:10.4f}" for x in result["rss_um"]))
    if "monte_carlo" in result:
        mc = result["monte_carlo"]
        print(f"  Monte Carlo ({mc['n']} trials, seed {mc['seed']}):")
        for p in ("50", "90", "98"):
            print(f"    {p}th percentile (um): "
                  + " ".join(f"{x:10.4f}" for x in mc["percentiles_um"][p]))
        print("    RMS over trials (um): " + " ".join(f"{x:10.4f}" for x in mc["rms_um"]))
    from .design.labels import parameter_label

    print("  largest sensitivities (um per unit: mm, rad, 1/mm; any field):")
    J = torch.tensor(result["sensitivity_um_per_unit"]).abs().max(0).values
    for j in J.argsort(descending=True)[:8].tolist():
        label, unit, _ = parameter_label(lens, names[j])
        print(f"    {names[j]:<28} {float(J[j]):.4g}   (+-{result['half_widths'][j]:g})   "
              f"{label}: {float(J[j]) * 1e-3:.4g} um per {unit}")
    return 0


def _design_help(prog: str) -> str:
    """``deeplens design --help``: every application with its whole first paragraph."""
    import textwrap

    from .design.apps import APPS, describe_app

    lines = [f"usage: {prog} NAME [options]   ({prog} NAME --help: that application's "
             f"options)", "", "run one of the paper's design applications:", ""]
    for name in APPS:
        try:
            text = describe_app(name)
        except ValueError as e:  # a module missing from this checkout
            text = str(e)
        lines.append(f"  {name}")
        lines += textwrap.wrap(text, 96, initial_indent="      ", subsequent_indent="      ")
    return "\n".join(lines)


def _design(name: str, rest: list, prog: str) -> int:
    from .design.apps import load_app

    if not any(a in ("-h", "--help") for a in rest) and _missing("design", "plot",
                                                                  ("matplotlib",)):
        return 2      # every application draws its figures

    try:
        app = load_app(name)
    except ValueError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    p = argparse.ArgumentParser(prog=f"{prog} {name}", description=(app.__doc__ or "").strip(),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--out", default=f"outputs/design/{name}",
                   help="folder for figures and files (default outputs/design/NAME)")
    app.add_arguments(p)
    args = p.parse_args(rest)
    try:
        result = app.run(args)
    except (ValueError, OSError) as e:
        print(f"{prog} {name}: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        for k, v in result.items():
            if isinstance(v, (int, float, str, bool)) or v is None:
                print(f"{k}: {v}")
        print(f"(all values: --json; figures in {args.out})")
    return 0


def _version() -> str:
    """``deeplens-do X.Y.Z (deeplens at PATH, torch V)``: the installed distribution's version
    (the package's own when run from a source checkout)."""
    from importlib.metadata import PackageNotFoundError, version
    from pathlib import Path

    from . import __file__ as init, __version__

    try:
        v = version("deeplens-do")
    except PackageNotFoundError:
        v = __version__
    if v != __version__:    # a checkout imported ahead of an installed distribution
        v = f"{__version__} (installed distribution deeplens-do {v})"
    try:
        from torch import __version__ as torch_version
    except ImportError:     # pragma: no cover - torch is a core dependency
        torch_version = "not installed"
    return f"deeplens-do {v} (deeplens at {Path(init).parent}, torch {torch_version})"


#: Hydra applications: every argument after the command is a Hydra override
_HYDRA_COMMANDS = {"train": "end-to-end training: deeplens train experiment=edof|doublet "
                            "[KEY=VALUE ...] (Hydra overrides; --help lists the config groups)",
                   "eval": "optical variants x seeds, each with its own restorer: deeplens eval "
                           "experiment=edof [KEY=VALUE ...]"}


def _main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv == ["--version"]:       # printed whole (argparse's version action wraps lines)
        print(_version())
        return 0
    if argv and argv[0] in _HYDRA_COMMANDS:     # Hydra parses its own command line
        if _missing(argv[0], "train"):
            return 2
        from .evaluation.entry import run

        run(argv[0], argv[1:])
        return 0
    p = argparse.ArgumentParser(prog="deeplens", description="deeplens command line",
                                epilog=f"LENS is a lens file or a shipped lens: "
                                       f"{', '.join(_shipped_names())} (deeplens lenses)")
    # handled above (the version string imports torch: not built for every command)
    p.add_argument("--version", action="store_true",
                   help="print the version, where deeplens is imported from, and torch's version")
    sub = p.add_subparsers(dest="cmd", required=True)
    for name, text in _HYDRA_COMMANDS.items():      # listed in -h; handled above
        sub.add_parser(name, help=text)
    r = sub.add_parser("report", help="paraxial data and RMS spots of a lens file")
    r.add_argument("lens", help=_lens_help())
    r.add_argument("--fields", help="field angles in degrees, e.g. 0,7,14,21 (default: file's)")
    r.add_argument("--wavelengths", help="wavelengths in nm, e.g. 486.1,587.6 (default: file's)")
    _add_sampling_option(r)
    r.add_argument("--pupil", choices=["traced", "paraxial"], default=None,
                   help="sample the pupil found by tracing or the paraxial EP (default: traced; "
                        "for a .zmx file, what its RAIM line says: paraxial without ray aiming)")
    r.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    r.add_argument("--json", action="store_true", help="print JSON instead of a table")
    r.add_argument("--config", type=int, metavar="N",
                   help="configuration N (from 1) of a multi-configuration Zemax file (MNUM: "
                        "zoom, focus), or zoom position N of a CODE V zoom lens (ZOO); default: "
                        "the active one, as saved (a .seq file: position 1)")
    r.add_argument("--analysis", help="also compute these, comma-separated: cardinal,distortion,"
                                      "field,color,vignetting,wavefront,strehl,mtf,ee")
    _add_lens_options(r)
    r.set_defaults(func=_report)
    ls = sub.add_parser("lenses", help="the shipped lenses: name, EFL, F/#, elements")
    ls.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ls.set_defaults(func=_lenses)
    _add_plot_parser(sub)
    _add_render_parser(sub)

    o = sub.add_parser("optimize", help="optimise lens variables for the RMS spot")
    o.add_argument("lens", help=_lens_help())
    o.add_argument("--vary", required=True,
                   help="parameter names or globs, comma-separated (e.g. 'surfaces.*.c')")
    o.add_argument("--fields", help="field angles in degrees (default: file's)")
    o.add_argument("--wavelengths", help="wavelengths in nm (default: file's)")
    o.add_argument("--method", choices=["dls", "adam", "lbfgs"], default="dls")
    o.add_argument("--steps", type=int, default=30)
    o.add_argument("--jacobian", choices=["auto", "forward", "reverse", "central"],
                   default="auto", help="DLS Jacobian: forward/reverse AD or float64 central "
                   "differences (cheapest for tens of variables; auto: forward when variables "
                   "<= residuals)")
    o.add_argument("--rounds", type=int, default=1, help="pupil re-sampling rounds")
    o.add_argument("--constraint", action="append", metavar="NAME=VALUE",
                   help="e.g. min_edge_air=0.5, max_track=60, efl=50 (repeatable)")
    _add_sampling_option(o, " of the merit and the RMS table")
    o.add_argument("--reference", choices=["centroid", "chief"], default="centroid")
    o.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    o.add_argument("--allow-vignetting", action="store_true",
                   help="let a trial step vignette rays (they leave the merit) instead of "
                        "rejecting it; the default rejects such steps so that the merit never "
                        "improves by losing rays")
    o.add_argument("--refocus", choices=["auto", "always", "never"], default="auto",
                   help="quick focus (sensor distance for the least RMS spot, closed form) "
                        "before optimising: auto does it when that at least halves the RMS "
                        "spot (default auto; only with --image-plane sensor)")
    o.add_argument("-v", "--verbose", action="store_true",
                   help="print every trial step: accepted (merit) or rejected (why)")
    o.add_argument("--out", required=True, help="where to write the optimised lens (.json)")
    o.add_argument("--json", action="store_true")
    _add_lens_options(o)
    o.set_defaults(func=_optimize)

    t = sub.add_parser("tolerance", help="sensitivities, RSS estimate and Monte Carlo")
    t.add_argument("lens", help=_lens_help())
    t.add_argument("--tolerances", help="JSON file: name/glob -> half-width (default: "
                                        "20 um, 0.5 mrad, 20 um spacing, 0.5%% curvature)")
    t.add_argument("--group", help="a tolerance group (configs/tolerance/NAME.yaml, by name or "
                                   "path): the distributions training and eval use")
    t.add_argument("--monte-carlo", type=int, default=0, metavar="N", help="trials (0: none)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--fields", help="field angles in degrees (default: file's)")
    t.add_argument("--wavelengths", help="wavelengths in nm (default: file's primary)")
    _add_sampling_option(t)
    t.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    t.add_argument("--out", help="folder for the Monte Carlo histogram (PNG)")
    t.add_argument("--json", action="store_true")
    _add_lens_options(t)
    t.set_defaults(func=_tolerance)

    d = sub.add_parser("design", help="run one of the paper's design applications, or design "
                                      "search from a specification", add_help=False)
    d.add_argument("name", help="spherical-aberration, nikon, sensitivity, caustic, "
                                "misalignment, search (deeplens design --help: what each does)")
    d.add_argument("rest", nargs=argparse.REMAINDER)
    d.set_defaults(func=None)
    words = sys.argv[1:] if argv is None else list(argv)
    if words[:1] == ["design"] and (len(words) == 1 or words[1] in ("-h", "--help")):
        print(_design_help("deeplens design"), file=sys.stdout if len(words) > 1 else sys.stderr)
        return 0 if len(words) > 1 else 2
    args = p.parse_args(argv)
    if args.cmd == "design":
        return _design(args.name, args.rest, "deeplens design")
    return args.func(args)


def main(argv=None) -> int:
    """The ``deeplens`` command.  Output piped into a reader that stops early (``deeplens report
    LENS | head``) ends the command quietly with status 141 (128 + SIGPIPE, as a Unix tool
    killed by SIGPIPE), not with a ``BrokenPipeError`` traceback.  The known warnings that say
    nothing about the user's work (:data:`deeplens.training.console.NOISY_WARNINGS`, e.g.
    torch's own ``torch.jit.script`` deprecation on the first forward-mode Jacobian) are not
    shown."""
    import warnings

    from .training.console import NOISY_WARNINGS

    try:
        with warnings.catch_warnings():     # torch's own deprecations, not the user's news
            for pattern in NOISY_WARNINGS:
                warnings.filterwarnings("ignore", message=pattern)
            return _main(argv)
    except BrokenPipeError:
        # the reader is gone: point stdout at /dev/null so the interpreter's final flush is quiet
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
