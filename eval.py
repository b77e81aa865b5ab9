"""Compare optical variants, each with its own restorer: python eval.py experiment=edof
(variants x seeds fanned out through a Hydra launcher: eval.launcher=joblib eval.n_jobs=2)."""

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

from deeplens.training.evaluate import evaluate


@hydra.main(version_base="1.3", config_path="configs", config_name="eval.yaml")
def main(cfg: DictConfig) -> None:
    if cfg.eval.get("launcher") and cfg.eval.get("job") is None and not cfg.eval.get("gather"):
        from deeplens.training.fanout import fan_out

        fan_out(cfg, __file__, list(HydraConfig.get().overrides.task))
        with open_dict(cfg):
            cfg.eval.gather = True
    table, _ = evaluate(cfg)
    print(table)


if __name__ == "__main__":
    main()
