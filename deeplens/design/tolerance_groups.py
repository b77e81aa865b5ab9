"""Tolerance groups from files: ``configs/tolerance/<name>.yaml``, a YAML file or a mapping
(an omegaconf ``DictConfig`` too), read into a :class:`~deeplens.optics.tolerance_model.
ToleranceModel`.  The model itself lives in the optics layer (it needs only the lens); reading
YAML and Hydra's configs stays here."""

from __future__ import annotations

from pathlib import Path

from ..optics.errors import ConfigError
from ..optics.tolerance_model import ToleranceModel
from ..resources import config_dir

__all__ = ["CONFIG_DIR", "load_group"]

#: the packaged tolerance groups (``configs/tolerance/<name>.yaml`` of the repository)
CONFIG_DIR = config_dir() / "tolerance"


def _plain(node):
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(node, DictConfig):
            return OmegaConf.to_container(node, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    return node


def load_group(spec, where: str = "tolerance") -> ToleranceModel:
    """A :class:`~deeplens.optics.tolerance_model.ToleranceModel` from a group name
    (``configs/tolerance/<name>.yaml``), a YAML file path or a mapping; errors name ``where``
    and the key."""
    spec = _plain(spec)
    if isinstance(spec, (str, Path)):
        p = Path(spec)
        if not p.suffix:
            p = CONFIG_DIR / f"{spec}.yaml"
        if not p.is_file():
            groups = sorted(q.stem for q in CONFIG_DIR.glob("*.yaml"))
            raise ConfigError(where, f"a tolerance group ({', '.join(groups)}), a .yaml file "
                              f"or a mapping", str(spec))
        import yaml

        try:
            data = yaml.safe_load(p.read_text())
        except yaml.YAMLError as e:
            raise ConfigError(where, f"a valid YAML file ({e})", str(p)) from None
        if data is not None and not isinstance(data, dict):
            raise ConfigError(where, "a YAML mapping of the group's keys", data, source=p)
        try:
            return ToleranceModel(data, where=where)
        except ConfigError as e:  # the key, and the file it came from
            raise e.with_source(p) from None
    if spec is None or isinstance(spec, dict):
        return ToleranceModel(spec, where=where)
    raise ConfigError(where, "a group name, a .yaml file or a mapping", spec)
