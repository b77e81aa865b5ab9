"""Bitwise before/after record of one end-to-end training step (issue 24's camera).

Moving the trace settings and the lens into one :class:`~deeplens.optics.camera.Camera` must
leave every value and gradient of a training step bit for bit as it was.  This script builds
two small runs from the real Hydra configs (``experiment=edof``: PSF-convolution renderer with
the Wiener front end and a trainable plate; ``experiment=doublet``: the Monte Carlo renderer
with adjoint gradients and trainable aspheres), takes one training step's loss on a fixed
batch (``EndToEndModule.step_loss``) and its backward pass, and stores the raw bytes of the
sensor image, the ground truth, the restored image, the loss, and the gradient of every
trainable parameter (lens, Wiener filter, restorer), plus the module's state-dict keys (a
checkpoint of the old code must still load).

Usage (from the repository root, one thread)::

    OMP_NUM_THREADS=1 python benchmarks/camera_step_bitwise.py record before.pt   # at the base
    OMP_NUM_THREADS=1 python benchmarks/camera_step_bitwise.py record after.pt
    python benchmarks/camera_step_bitwise.py compare before.pt after.pt

``compare`` prints the entries that differ and exits non-zero unless everything is identical.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RUNS = {
    "edof": ["experiment=edof", "render.psf_rays=1024", "render.psf_model=geometric",
             "model.deconvolution.rays=1024", "model.deconvolution.depths=3",
             "model.optics_warmup_steps=0", "lens.dtype=float64"],
    "edof_auto": ["experiment=edof", "render.psf_rays=1024", "model.deconvolution.rays=1024",
                  "model.deconvolution.depths=2", "model.optics_warmup_steps=0"],
    "doublet": ["experiment=doublet", "render=fast", "render.spp=2", "render.psf_model=geometric"],
}
TINY = ["sensor.resolution=[16,16]", "data.image_size=32", "data.batch_size=2",
        "data.train_steps_per_epoch=1", "data.val_size=2", "data.test_size=2",
        "trainer.max_epochs=1"]


def compose(overrides, out: str):
    from hydra import compose as hcompose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        cfg = hcompose(config_name="train.yaml", return_hydra_config=True,
                       overrides=TINY + list(overrides))
    HydraConfig().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = out
        cfg.paths.root_dir = str(REPO)
        cfg.paths.data_dir = str(REPO / "data")
    return cfg


def one_step(name: str, overrides, out: str) -> dict:
    from deeplens.training.train import build_objects

    cfg = compose(overrides, out)
    objs = build_objects(cfg)
    module = objs["module"]
    g = torch.Generator().manual_seed(1234)
    images = torch.rand(2, 3, 32, 32, generator=g)
    loss, terms, y, gt, pred = module.step_loss(images, 0)
    loss.backward()
    rec = {f"{name}/loss": loss.detach(), f"{name}/sensor": y.detach(),
           f"{name}/gt": gt.detach(), f"{name}/restored": pred.detach()}
    rec.update({f"{name}/term/{k}": v.detach() for k, v in terms.items()})
    for n, p in module.named_parameters():
        if p.requires_grad and (n.startswith("lens.") or n.startswith("deconv.")
                                or n.startswith("restorer.")):
            rec[f"{name}/grad/{n}"] = (p.grad.detach().clone() if p.grad is not None
                                       else torch.tensor(float("nan")))
    rec[f"{name}/state_dict_keys"] = sorted(module.state_dict())
    return rec


def record(path: str, runs) -> None:
    import tempfile

    torch.manual_seed(0)
    out = {}
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in runs:
            out.update(one_step(name, RUNS[name], tmp))
            print(f"{name}: recorded", flush=True)
    torch.save({k: (v if isinstance(v, list) else
                    (str(v.dtype), tuple(v.shape), v.contiguous().cpu().numpy().tobytes()))
                for k, v in out.items()}, path)
    print(f"{len(out)} entries -> {path}")


def compare(a: str, b: str) -> int:
    A, B = torch.load(a, weights_only=False), torch.load(b, weights_only=False)
    bad = 0
    for k in sorted(set(A) | set(B)):
        if k not in A or k not in B:
            print(f"only in {'before' if k in A else 'after'}: {k}")
            bad += 1
        elif A[k] != B[k]:
            print(f"differs: {k}")
            bad += 1
    print(f"{len(set(A) & set(B))} common entries, {bad} differ or are missing")
    return 1 if bad else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("path")
    r.add_argument("--runs", nargs="*", default=list(RUNS))
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    args = ap.parse_args()
    if args.cmd == "record":
        record(args.path, args.runs)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
