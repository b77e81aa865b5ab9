"""Command line: ``deeplens report LENS [options]``."""

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

    from .analysis.report import format_report, lens_report
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
        rep = lens_report(lens, fields, waves, args.sampling, args.pupil, args.image_plane)
    except (ValueError, OSError) as e:
        print(f"deeplens report: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(rep, indent=1) if args.json else format_report(rep))
    return 0


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
    r.set_defaults(func=_report)
    args = p.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
