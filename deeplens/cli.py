"""Command line: ``deeplens report LENS [options]`` and ``deeplens plot LENS --kind K -o OUT``."""

from __future__ import annotations

import argparse
import json
import math
import sys

__all__ = ["main"]


class _UsageError(ValueError):
    """A bad command-line value (exit status 2, like argparse's own errors)."""


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


def _report(args) -> int:
    import torch

    from .analysis.report import analysis_report, format_report, lens_report
    from .optics.io import load_lens
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
        lens = load_lens(args.lens).to(torch.float64)
        if waves:
            for i, m in enumerate(lens.materials):
                medium = "object space" if i == 0 else f"the medium after surface {i - 1}"
                try:
                    check_wavelength_nm(waves, m)
                except ValueError as e:
                    raise _UsageError(f"--wavelengths: {e} ({medium} of {args.lens})") from None
        kinds = _analysis_kinds(args.analysis) if args.analysis is not None else None
        rep = lens_report(lens, fields, waves, args.sampling, args.pupil, args.image_plane)
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
    import torch

    from .analysis.plot import plot
    from .optics.io import load_lens

    try:
        fields = waves = None
        if args.fields is not None:
            fields = _floats(args.fields, "--fields", "degrees (e.g. 0,7,14)")
            if not all(abs(f) < 90 for f in fields):
                raise _UsageError(f"--fields: field angles are in degrees and must lie within "
                                  f"(-90, 90), got {args.fields!r}")
        if args.wavelengths is not None:
            waves = _floats(args.wavelengths, "--wavelengths", "nm (e.g. 486.1,587.6)")
        lens = load_lens(args.lens).to(torch.float64)
        plot(lens, args.kind, args.output, fields, waves, image_plane=args.image_plane)
    except (ValueError, OSError) as e:
        print(f"deeplens plot: error: {e}", file=sys.stderr)
        return 2
    print(args.output)
    return 0


def _add_plot_parser(sub) -> None:
    from .analysis.plot import KINDS

    q = sub.add_parser("plot", help="draw an analysis figure of a lens file as a PNG")
    q.add_argument("lens", help="lens file (.json, or the paper authors' .txt table)")
    q.add_argument("--kind", required=True, choices=list(KINDS), help="which figure")
    q.add_argument("--fields", help="field angles in degrees, e.g. 0,7,14,21 (default: file's)")
    q.add_argument("--wavelengths", help="wavelengths in nm, e.g. 486.1,587.6 (default: "
                                         "file's; the first is used for monochromatic plots)")
    q.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    q.add_argument("-o", "--output", required=True, help="output PNG path")
    q.set_defaults(func=_plot)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="deeplens", description="deeplens command line")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("report", help="paraxial data and RMS spots of a lens file")
    r.add_argument("lens", help="lens file (.json, the paper authors' .txt table, or Zemax .zmx)")
    r.add_argument("--fields", help="field angles in degrees, e.g. 0,7,14,21 (default: file's)")
    r.add_argument("--wavelengths", help="wavelengths in nm, e.g. 486.1,587.6 (default: file's)")
    r.add_argument("--sampling", default="hexapolar:18",
                   help="pupil sampling: hexapolar:RINGS, grid:N or random:N[:SEED]")
    r.add_argument("--pupil", choices=["traced", "paraxial"], default="traced",
                   help="sample the pupil found by tracing (default) or the paraxial EP")
    r.add_argument("--image-plane", choices=["sensor", "paraxial"], default="sensor")
    r.add_argument("--json", action="store_true", help="print JSON instead of a table")
    r.add_argument("--analysis", help="also compute these, comma-separated: cardinal,distortion,"
                                      "field,color,vignetting,wavefront,strehl,mtf,ee")
    r.set_defaults(func=_report)
    _add_plot_parser(sub)
    args = p.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
