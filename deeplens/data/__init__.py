"""Procedural training data: seeded textures (no downloads) and Lightning data loading.

:mod:`.textures` needs only torch; :mod:`.datamodule` (``TextureDataset``,
``EndlessTextureDataset``, ``ImageFolderDataset``, ``TextureDataModule``, ``EpochLoader``) needs
the ``train`` extras (lightning, torchvision) and is imported on first use.
"""

from .textures import (
    TEXTURE_KINDS,
    TEXTURES,
    RandomPalette,
    checkerboard,
    dead_leaves,
    fractal_noise,
    grating,
    random_texture,
    strokes,
    voronoi,
)

_DATAMODULE_NAMES = ("TextureDataset", "EndlessTextureDataset", "ImageFolderDataset",
                     "CenterCropFolderDataset",
                     "TextureDataModule", "EpochLoader")

__all__ = [
    "TEXTURE_KINDS", "TEXTURES", "RandomPalette", "checkerboard", "dead_leaves",
    "fractal_noise", "grating", "random_texture", "strokes", "voronoi", *_DATAMODULE_NAMES,
]


def __getattr__(name):
    if name in _DATAMODULE_NAMES:
        from . import datamodule
        return getattr(datamodule, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
