"""Compare no plate / cubic plate / learned plate, each with its restorer:
python eval.py experiment=edof"""

import hydra
from omegaconf import DictConfig

from deeplens.training.evaluate import evaluate


@hydra.main(version_base="1.3", config_path="configs", config_name="eval.yaml")
def main(cfg: DictConfig) -> None:
    table, _ = evaluate(cfg)
    print(table)


if __name__ == "__main__":
    main()
