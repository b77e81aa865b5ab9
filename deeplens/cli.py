"""Command line: ``deeplens report LENS [options]``."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["main"]


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"deeplens: {what} must be comma-separated numbers, got {text!r}")


def _report(args) -> int:
    import torch

    from .analysis.report import format_report, lens_report
    from .optics.io import load_lens
    from .optics.sampling import parse_sampling

    try:
        parse_sampling(args.sampling)
        lens = load_lens(args.lens).to(torch.float64)
        fields = _floats(args.fields, "--fields") if args.fields else None
        waves = _floats(args.wavelengths, "--wavelengths") if args.wavelengths else None
        if waves:
            from .optics.materials import check_wavelength_nm

            check_wavelength_nm(waves, where="--wavelengths: ")
        rep = lens_report(lens, fields, waves, args.sampling, args.pupil, args.image_plane)
    except (ValueError, FileNotFoundError) as e:
        print(f"deeplens report: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(rep, indent=1) if args.json else format_report(rep))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="deeplens", description="deeplens command line")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("report", help="paraxial data and RMS spots of a lens file")
    r.add_argument("lens", help="lens file (.json, or the paper authors' .txt table)")
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
