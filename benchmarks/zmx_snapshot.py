"""Bitwise record of what the Zemax reader and writer produce (issue 24's split of ``zmx.py``).

For every ``.zmx`` under ``tests/data`` (the shipped lenses and the real-file corpus
``tests/data/zmx_real``) it records either the lens ``read_zmx`` builds -- every parameter and
buffer of every surface, material, distance and misalignment as a float hex string, the stop,
mirrors, elements, spec, ray aiming, surface types and each material's index at every wavelength
-- with the warnings raised, the ``.zmx`` text ``write_zmx`` writes for it and the re-read of that
text; or the refusal (exception type and message).  A refactor of the reader must leave the
record bit for bit unchanged.

Usage (from the repository root, one thread)::

    OMP_NUM_THREADS=1 python benchmarks/zmx_snapshot.py record before.json
    OMP_NUM_THREADS=1 python benchmarks/zmx_snapshot.py record after.json
    python benchmarks/zmx_snapshot.py compare before.json after.json

``compare`` prints every entry that differs and exits non-zero unless all are identical.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import warnings
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _hex(t) -> list | str:
    t = torch.as_tensor(t)
    if t.is_floating_point():
        return [float(v).hex() for v in t.detach().reshape(-1).tolist()]
    return [repr(v) for v in t.detach().reshape(-1).tolist()]


def lens_record(lens) -> dict:
    """Everything about ``lens`` that the reader decides, as JSON-able exact values."""
    rec = {"state": {k: _hex(v) for k, v in lens.state_dict().items()},
           "types": [type(s).__name__ for s in lens.surfaces],
           "materials": [f"{type(m).__name__}:{m.name}" for m in lens.materials],
           "stop_index": lens.stop_index, "mirrors": sorted(lens.mirrors),
           "elements": [list(e) for e in lens.elements], "name": lens.name,
           "ray_aiming": bool(getattr(lens, "ray_aiming", False)),
           "sensor_sd": (None if lens.sensor_semi_diameter is None
                         else float(lens.sensor_semi_diameter).hex())}
    spec = lens.spec
    rec["spec"] = {"object_distance_mm": float(spec.object_distance_mm).hex(),
                   "aperture_type": spec.aperture_type,
                   "aperture_value": (None if spec.aperture_value is None
                                      else float(spec.aperture_value).hex()),
                   "fields_deg": [float(f).hex() for f in spec.fields_deg],
                   "wavelengths_nm": [float(w).hex() for w in spec.wavelengths_nm],
                   "primary": float(spec.primary_wavelength_nm).hex()}
    with torch.no_grad():
        rec["n"] = [[float(m.n(torch.tensor(float(w), dtype=torch.float64))).hex()
                     for w in spec.wavelengths_nm] for m in lens.materials]
    return rec


def read_record(path: Path) -> dict:
    from deeplens.optics.io.zmx import read_zmx, write_zmx

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            lens = read_zmx(path)
        except Exception as e:   # noqa: BLE001 -- the refusal is what is recorded
            return {"error": f"{type(e).__name__}: {e}",
                    "warnings": [str(w.message) for w in caught]}
    out = {"lens": lens_record(lens), "warnings": [str(w.message) for w in caught]}
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "out.zmx"
        try:
            write_zmx(lens, f)
        except Exception as e:   # noqa: BLE001
            out["write_error"] = f"{type(e).__name__}: {e}".replace(d, "<tmp>")
            return out
        out["written"] = f.read_text()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                out["reread"] = lens_record(read_zmx(f))
            except Exception as e:   # noqa: BLE001
                out["reread_error"] = f"{type(e).__name__}: {e}".replace(d, "<tmp>")
    return out


def record(dest: Path) -> None:
    torch.set_default_dtype(torch.float64)
    files = sorted(p for p in (REPO / "tests" / "data").rglob("*") if p.suffix.lower() == ".zmx")
    data = {}
    for p in files:
        key = str(p.relative_to(REPO))
        data[key] = read_record(p)
        print(key, "refused" if "error" in data[key] else "loaded", flush=True)
    dest.write_text(json.dumps(data, indent=1, sort_keys=True))


def _diff(a, b, where: str, out: list) -> None:
    if type(a) is not type(b):
        out.append(f"{where}: {a!r} != {b!r}")
    elif isinstance(a, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{where}.{k}: only in {'after' if k not in a else 'before'}")
            else:
                _diff(a[k], b[k], f"{where}.{k}", out)
    elif isinstance(a, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, f"{where}[{i}]", out)
    elif a != b:
        out.append(f"{where}: {str(a)[:300]!r} != {str(b)[:300]!r}")


def compare(before: Path, after: Path) -> int:
    a, b = json.loads(before.read_text()), json.loads(after.read_text())
    out: list[str] = []
    _diff(a, b, "", out)
    for line in out:
        print(line)
    print(f"{len(a)} files, {len(out)} differences")
    return 1 if out else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("dest", type=Path)
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.dest)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
