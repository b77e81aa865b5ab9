"""Which manufacturing error dominates: RMS spot of lenses drawn from a tolerance group with one
kind of error at a time (docs/results/doublet_tolerance.md).

For each lens file and each error kind of the group alone (the group's compensator kept), then
all kinds with and without the compensator, ``N`` lenses are drawn with seeds ``0 .. N-1`` (the
lenses ``eval.tolerance`` tests) and the RMS spot (µm, centroid reference, on the sensor,
hexapolar:6 pupil, the sensor's R/G/B wavelengths) is traced per field, with the shift of the
spot's centroid from the nominal lens's (µm, mean over wavelengths): the RMS spot about the
centroid does not see an image that moves.  Prints one row per lens and kind: the nominal spot,
the mean and 95th percentile over the draws, per field, then the shift's mean and 95th pct.

    OMP_NUM_THREADS=1 python benchmarks/doublet_tolerance_breakdown.py \
        [--group commercial] [--n 64] [--fields 0,10,20] [--psnr-from EVAL_TABLE.json] \
        [--figure PNG] [--json OUT.json] NAME=LENS.json ...

``--psnr-from``: an ``eval_table.json`` of ``eval.tolerance`` (same group, seed 0, ``N``
lenses) whose variants are named like the lenses: the correlation of each drawn lens's restored
PSNR with its image shift (and ``--figure``, the scatter of the two).
"""

from __future__ import annotations

import argparse
import json

import torch

from deeplens.design.merit import SpotMerit
from deeplens.design.sensitivity import field_merits
from deeplens.design.tolerance_groups import CONFIG_DIR, load_group
from deeplens.optics.tolerance_model import KINDS, call_drawn
from deeplens.optics.io import load_lens
from deeplens.render.sensor import Sensor


def centroids(merit: SpotMerit, lens) -> torch.Tensor:
    """Spot centroids ``(F, W, 2)`` (mm) on the merit's image plane."""
    from deeplens.design.merit import image_plane_z

    keys = [(f, w) for f in merit.fields for w in merit.waves]
    rays, sl = merit._bundle(lens, keys)
    out = lens.trace_to_sensor(rays, z_image=image_plane_z(lens, merit.image_plane))
    c = []
    for k in keys:
        ok = (out.valid[sl[k]] & merit.masks[k]).unsqueeze(-1).to(out.o.dtype)
        c.append((out.o[sl[k], :2] * ok).sum(0) / ok.sum().clamp(min=1))
    return torch.stack(c).reshape(len(merit.fields), len(merit.waves), 2)


def breakdown(lens, group, n: int, fields, waves) -> dict:
    """``{kind: {"nominal_um", "mean_um", "p95_um", "shift_mean_um", "shift_p95_um"}}`` (per
    field; the shift: of the spot's centroid from the nominal lens's, mean over λ), and the
    per-draw values ``spot_um``, ``shift_um`` ``(n, F)``, for each kind of ``group`` alone,
    ``all`` and ``all, no compensator``."""
    base = _group_dict(group)
    merit = SpotMerit(fields, waves, strict_rays=False).prepare(lens)
    with torch.no_grad():
        nominal, c0 = field_merits(merit, lens), centroids(merit, lens)

    def trial(L):  # RMS spot (F,) and the centroid's shift from nominal, averaged over λ (F,)
        return torch.stack([field_merits(merit, L),
                            (centroids(merit, L) - c0).norm(dim=-1).mean(-1)])

    runs = {k: {**{q: None for q in KINDS}, k: base[k], "compensator": base.get("compensator")}
            for k in KINDS if base.get(k) is not None}
    runs["all"] = dict(base)
    runs["all, no compensator"] = {**base, "compensator": None}
    out = {}
    for name, spec in runs.items():
        model = load_group({k: v for k, v in spec.items() if k != "name"})
        with torch.no_grad():
            t = torch.stack([call_drawn(lens, model.draw(lens, k), trial) for k in range(n)])
        s, sh = t[:, 0], t[:, 1]
        out[name] = {"nominal_um": (nominal * 1e3).tolist(), "mean_um": (s.mean(0) * 1e3).tolist(),
                     "p95_um": (torch.quantile(s, 0.95, dim=0) * 1e3).tolist(),
                     "shift_mean_um": (sh.mean(0) * 1e3).tolist(),
                     "shift_p95_um": (torch.quantile(sh, 0.95, dim=0) * 1e3).tolist(),
                     "spot_um": (s * 1e3).tolist(), "shift_um": (sh * 1e3).tolist()}
    return out


def psnr_vs_shift(res: dict, eval_json: str, kind: str = "all") -> dict:
    """For each lens named like a variant of ``eval_json``'s tolerance block (an
    ``eval_table.json`` of ``eval.tolerance`` with the same group, seed 0 and the same number of
    drawn lenses): the Pearson correlation over the drawn lenses between the restored PSNR
    (whole image and edge band) and the image shift at each field, and the PSNR drop (dB) per
    10 µm of shift (least squares)."""
    tol = json.loads(open(eval_json).read())["tolerance"]
    out = {}
    for name, r in res.items():
        runs = tol["variants"].get(name)
        if not runs:
            continue
        shift = torch.tensor(r[kind]["shift_um"], dtype=torch.float64)
        for col in ("mean", "band 0.66-1"):
            p = torch.tensor(runs[0]["columns"][col]["psnr"], dtype=torch.float64)
            if p.numel() != shift.shape[0]:
                raise ValueError(f"{eval_json}: {p.numel()} drawn lenses, breakdown has "
                                 f"{shift.shape[0]} (--n)")
            for f in range(shift.shape[1]):
                x = shift[:, f] - shift[:, f].mean()
                y = p - p.mean()
                corr = float((x * y).sum() / (x.norm() * y.norm()))
                slope = float((x * y).sum() / (x * x).sum()) * 10.0
                out.setdefault(name, {}).setdefault(col, []).append(
                    {"corr": corr, "db_per_10um": slope})
    return out


def psnr_shift_figure(res: dict, eval_json: str, path: str, kind: str = "all") -> None:
    """Scatter of the restored PSNR (whole image) of every drawn lens against its on-axis
    image shift, one colour per lens named like a variant of ``eval_json``."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    tol = json.loads(open(eval_json).read())["tolerance"]
    fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=100)
    for name, r in res.items():
        if tol["variants"].get(name):
            shift = [v[0] for v in r[kind]["shift_um"]]
            ax.scatter(shift, tol["variants"][name][0]["columns"]["mean"]["psnr"], s=12,
                       label=name)
    ax.set_xlabel("image shift on axis (µm; pixel 80.4 µm)")
    ax.set_ylabel("restored PSNR (dB)")
    ax.set_title("drawn lenses: PSNR follows where the image lands")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def _group_dict(group: str) -> dict:
    """The group's mapping (a name of configs/tolerance or a .yaml file), checked."""
    import yaml
    from pathlib import Path

    load_group(group, where="--group")  # the group's own checks and messages
    p = Path(group) if group.endswith(".yaml") else CONFIG_DIR / f"{group}.yaml"
    return yaml.safe_load(p.read_text())


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("lenses", nargs="+", help="NAME=LENS.json")
    ap.add_argument("--group", default="commercial")
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--fields", default="0,10,20")
    ap.add_argument("--json", help="write the numbers here")
    ap.add_argument("--figure", help="with --psnr-from: PNG of PSNR vs on-axis image shift")
    ap.add_argument("--psnr-from", metavar="EVAL_TABLE.json",
                    help="correlate the restored PSNR of its drawn lenses (variants named like "
                         "the lenses) with the image shift")
    a = ap.parse_args()
    fields = [float(f) for f in a.fields.split(",")]
    waves = [float(w) for ch in Sensor((8, 8), 0.1).channels for w in ch]
    res = {}
    print(f"group {a.group}, {a.n} draws (seeds 0..{a.n - 1}), RMS spot (um) at fields "
          f"{fields} deg, wavelengths {waves} nm: nominal | mean over draws | 95th pct")
    print("| lens | errors | " + " | ".join(f"{f:g}°: nominal / mean / p95" for f in fields)
          + " | " + " | ".join(f"{f:g}° shift: mean / p95" for f in fields) + " |")
    print("|---|---|" + "---|" * 2 * len(fields))
    for item in a.lenses:
        name, path = item.split("=", 1)
        lens = load_lens(path).double()
        res[name] = breakdown(lens, a.group, a.n, fields, waves)
        for kind, r in res[name].items():
            print(f"| {name} | {kind} | " + " | ".join(
                f"{r['nominal_um'][f]:.1f} / {r['mean_um'][f]:.1f} / {r['p95_um'][f]:.1f}"
                for f in range(len(fields))) + " | " + " | ".join(
                f"{r['shift_mean_um'][f]:.1f} / {r['shift_p95_um'][f]:.1f}"
                for f in range(len(fields))) + " |")
    corr = psnr_vs_shift(res, a.psnr_from) if a.psnr_from else {}
    for name, cols in corr.items():
        for col, per_field in cols.items():
            print(f"{name}, restored PSNR ({col}) vs image shift over the drawn lenses: " + ", ".join(
                f"{fields[f]:g}°: r = {c['corr']:+.2f}, {c['db_per_10um']:+.2f} dB / 10 um"
                for f, c in enumerate(per_field)))
    if a.figure and a.psnr_from:
        psnr_shift_figure(res, a.psnr_from, a.figure)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"group": a.group, "n": a.n, "fields_deg": fields, "wavelengths_nm": waves,
                       "lenses": res, "psnr_vs_shift": corr}, fh, indent=1)
