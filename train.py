"""Train an end-to-end camera:  python train.py experiment=edof  (or experiment=doublet)."""

import hydra
from omegaconf import DictConfig

from deeplens.training.train import train


@hydra.main(version_base="1.3", config_path="configs", config_name="train.yaml")
def main(cfg: DictConfig) -> float | None:
    metrics, _ = train(cfg)
    return metrics.get("val/psnr_restored")


if __name__ == "__main__":
    main()
