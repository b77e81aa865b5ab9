"""Datasets and the Lightning data module for end-to-end training on procedural textures.

Seeding (everything is reproducible from one integer ``seed``, nothing is downloaded):

* fixed sets (:class:`TextureDataset`): item ``k`` is generated from seed ``base_seed + k``, so it
  does not depend on workers, order or batch size.  :class:`TextureDataModule` places the
  validation set at ``base = derive_seed(seed, "val")`` and the test set right after it
  (``base + val_size``): the two never share an item, and changing ``seed`` moves both.
* training streams (:class:`EndlessTextureDataset`, the image-folder stream): item ``i`` of epoch
  ``e`` is generated from ``derive_seed(seed, e, i)`` (a 62-bit hash, so training items are not
  validation items except with negligible probability).  With ``num_workers = W`` worker ``w``
  produces the chunks (of ``chunk_size`` items, the batch size in the data module) with
  ``chunk % W == w``; since a :class:`~torch.utils.data.DataLoader` takes batches from its
  workers in turn, the stream comes out in the same order for any number of workers.  The epoch
  is set by :meth:`set_epoch`; :class:`EpochLoader` calls it before every pass.
* resuming mid-epoch (``trainer.val_check_interval`` checkpoints, a stop by a signal): the
  :class:`EpochLoader` is stateful for Lightning (``state_dict``: the epoch of its pass and the
  batches the training loop has processed); loaded from a checkpoint, its next pass of that
  epoch starts at the next unseen item (``set_epoch(e, start=k)``), so a resumed run sees the
  items an uninterrupted one would.

Items are dicts: ``{"image": (3, H, W) float32 in [0, 1] (linear RGB), "kind": str, ...}``; the
default collate turns a batch into ``{"image": (B, 3, H, W), "kind": [str] * B, ...}``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import lightning as L
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset, IterableDataset, get_worker_info

from .textures import Size, as_generator, check_kinds, parse_size, random_texture

__all__ = [
    "derive_seed",
    "TextureDataset",
    "EndlessTextureDataset",
    "ImageFolderDataset",
    "CenterCropFolderDataset",
    "EpochLoader",
    "TextureDataModule",
]

_MASK64 = (1 << 64) - 1
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_int(name: str, value, minimum: int) -> int:
    if not _is_int(value) or value < minimum:
        what = "a positive int" if minimum == 1 else f"an int >= {minimum}"
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return int(value)


def _splitmix64(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK64
    return x ^ (x >> 31)


def derive_seed(*values: int | str) -> int:
    """Hash integers/strings into a seed in ``[0, 2^62)`` (SplitMix64 chained over the values).

    Each value is absorbed as a header word (type, sign, length) followed by its 64-bit words
    (the UTF-8 bytes of a string), so ``-1``, ``2**64 - 1``, ``"a"`` and ``97`` all differ.
    Deterministic across runs, processes and platforms (no Python ``hash``); used to give each
    (seed, epoch, item) and each split its own independent stream.
    """
    h = 0x243F6A8885A308D3
    for v in values:
        if isinstance(v, str):
            data, tag = v.encode("utf-8"), 1
        elif _is_int(v):
            mag = abs(v)
            data, tag = mag.to_bytes(max(1, (mag.bit_length() + 7) // 8), "little"), 2 + (v < 0)
        else:
            raise TypeError(f"derive_seed takes ints and strings, got {type(v).__name__}")
        words = [int.from_bytes(data[i:i + 8], "little") for i in range(0, len(data), 8)]
        h = _splitmix64(h ^ ((tag << 56) | len(data)))
        for word in words:
            h = _splitmix64(h ^ word)
    return h >> 2


class TextureDataset(Dataset):
    """A fixed set of ``n`` procedural textures: item ``k`` comes from seed ``base_seed + k``.

    Args:
        n: number of items (> 0).
        image_size: ``int`` or ``(H, W)`` pixels.
        base_seed: seed of item 0 (>= 0).
        kinds: texture kinds to draw from (see :data:`~deeplens.data.textures.TEXTURES`),
            default all.

    Items: ``{"image": (3, H, W) float32 in [0, 1], "kind": str, "seed": int}``.
    """

    def __init__(self, n: int, image_size: Size, base_seed: int = 0,
                 kinds: str | Iterable[str] | None = None):
        self.n = _check_int("n", n, 1)
        self.image_size = parse_size(image_size, "image_size")
        self.base_seed = _check_int("base_seed", base_seed, 0)
        self.kinds = check_kinds(kinds)

    def __len__(self) -> int:
        return self.n

    def seed_of(self, k: int) -> int:
        return self.base_seed + k

    def __getitem__(self, k: int) -> dict:
        if not _is_int(k) and not (torch.is_tensor(k) and k.ndim == 0):
            raise TypeError(f"TextureDataset index must be an int, got {type(k).__name__}")
        k = int(k)
        if k < 0:
            k += self.n
        if not 0 <= k < self.n:
            raise IndexError(f"TextureDataset index {k} out of range for {self.n} items")
        seed = self.seed_of(k)
        image, kind = random_texture(self.image_size, seed, self.kinds)
        return {"image": image, "kind": kind, "seed": seed}


class _SeededStream(IterableDataset):
    """Training stream base: item ``i`` of epoch ``e`` is ``make_item(derive_seed(seed, e, i))``.

    Split over DataLoader workers in chunks of ``chunk_size`` items (chunk ``c`` goes to worker
    ``c % num_workers``), and over distributed ranks by hashing the rank in (only when the world
    size is > 1, so a single process sees the same stream as before).
    """

    def __init__(self, seed: int, samples_per_epoch: int | None, chunk_size: int):
        self.seed = _check_int("seed", seed, 0)
        if samples_per_epoch is not None:
            samples_per_epoch = _check_int("samples_per_epoch", samples_per_epoch, 1)
        self.samples_per_epoch = samples_per_epoch
        self.chunk_size = _check_int("chunk_size", chunk_size, 1)
        self.epoch = 0
        self.start = 0

    def set_epoch(self, epoch: int, start: int = 0) -> None:
        """Select the epoch's stream (call before iterating; :class:`EpochLoader` does), from
        item ``start`` on (a multiple of ``chunk_size``: a resumed pass skips whole batches)."""
        self.epoch = _check_int("epoch", epoch, 0)
        start = _check_int("start", start, 0)
        if start % self.chunk_size:
            raise ValueError(f"set_epoch: start={start} is not a multiple of the chunk size "
                             f"{self.chunk_size}")
        self.start = start

    def __len__(self) -> int:
        if self.samples_per_epoch is None:
            raise TypeError(f"{type(self).__name__} is endless (samples_per_epoch=None): no len()")
        return self.samples_per_epoch

    def item_seed(self, i: int, epoch: int | None = None, rank: int | None = None) -> int:
        """The seed of item ``i`` of ``epoch`` (default the current one)."""
        epoch = self.epoch if epoch is None else epoch
        if rank is None:
            return derive_seed(self.seed, epoch, i)
        return derive_seed(self.seed, epoch, i, "rank", rank)

    def make_item(self, seed: int) -> dict:
        raise NotImplementedError

    def __iter__(self) -> Iterator[dict]:
        info = get_worker_info()
        wid, nw = (0, 1) if info is None else (info.id, info.num_workers)
        rank = None
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            if torch.distributed.get_world_size() > 1:
                rank = torch.distributed.get_rank()
        epoch, total, cs = self.epoch, self.samples_per_epoch, self.chunk_size
        chunk = self.start // cs + wid  # worker w still takes every nw-th chunk from the start
        while total is None or chunk * cs < total:
            stop = (chunk + 1) * cs if total is None else min((chunk + 1) * cs, total)
            for i in range(chunk * cs, stop):
                yield self.make_item(self.item_seed(i, epoch, rank))
            chunk += nw


class EndlessTextureDataset(_SeededStream):
    """Seeded stream of procedural textures for training, new ones every epoch.

    Args:
        image_size: ``int`` or ``(H, W)`` pixels.
        seed: stream seed (>= 0); item ``i`` of epoch ``e`` comes from
            ``derive_seed(seed, e, i)``.
        kinds: texture kinds, default all.
        samples_per_epoch: items per epoch (``len()``), or ``None`` for an endless stream.
        chunk_size: items handed to a worker at a time; use the batch size so that batches
            are full and the order does not depend on ``num_workers`` (see module docstring).

    Items: ``{"image": (3, H, W) float32 in [0, 1], "kind": str, "seed": int}``.
    """

    def __init__(self, image_size: Size, seed: int = 0, kinds: str | Iterable[str] | None = None,
                 samples_per_epoch: int | None = None, chunk_size: int = 1):
        super().__init__(seed, samples_per_epoch, chunk_size)
        self.image_size = parse_size(image_size, "image_size")
        self.kinds = check_kinds(kinds)

    def make_item(self, seed: int) -> dict:
        image, kind = random_texture(self.image_size, seed, self.kinds)
        return {"image": image, "kind": kind, "seed": seed}


def _srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 sRGB decoding: ``x/12.92`` below 0.04045, else ``((x + 0.055)/1.055)^2.4``."""
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


class ImageFolderDataset(Dataset):
    """The user's own images (``.png``, ``.jpg``, ``.jpeg``, searched recursively), cropped.

    Images are decoded to RGB (grey is replicated, alpha dropped), scaled to ``[0, 1]``
    (8- or 16-bit), decoded from sRGB to linear RGB unless ``linearize=False``, and randomly
    cropped to ``image_size``; images smaller than the crop are first enlarged (bilinear) just
    enough to hold it.

    Args:
        root: folder of images.
        image_size: crop size, ``int`` or ``(H, W)`` pixels.
        linearize: decode the sRGB transfer curve (textures are linear RGB).

    Item ``k``: a random crop of file ``k`` (offsets from torch's global RNG, which DataLoader
    workers seed per worker and epoch): ``{"image": (3, H, W) float32, "kind": "folder",
    "path": str}``.  :meth:`sample` draws a file and a crop from a given generator instead.

    Raises:
        FileNotFoundError: ``root`` is missing, not a folder, or holds no such image.
    """

    def __init__(self, root: str | Path, image_size: Size, linearize: bool = True):
        self.root = Path(root).expanduser()
        self.image_size = parse_size(image_size, "image_size")
        self.linearize = bool(linearize)
        if not self.root.exists():
            raise FileNotFoundError(f"image folder '{self.root}' does not exist")
        if not self.root.is_dir():
            raise FileNotFoundError(f"image folder '{self.root}' is not a directory")
        self.files = sorted(p for p in self.root.rglob("*")
                            if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
        if not self.files:
            raise FileNotFoundError(f"image folder '{self.root}' contains no images "
                                    f"({', '.join(IMAGE_EXTENSIONS)})")

    def __len__(self) -> int:
        return len(self.files)

    def load(self, k: int) -> torch.Tensor:
        """File ``k`` as ``(3, h, w)`` float32 in ``[0, 1]`` (linear unless ``linearize=False``)."""
        from torchvision.io import ImageReadMode, decode_image

        path = self.files[k]
        try:
            img = decode_image(str(path), mode=ImageReadMode.RGB)
        except Exception as err:  # noqa: BLE001 - re-raised with the file named
            raise RuntimeError(f"could not decode image '{path}': {err}") from err
        if img.dtype == torch.uint8:
            x = img.to(torch.float32) / 255.0
        elif img.dtype == torch.uint16:
            x = img.to(torch.float32) / 65535.0
        else:
            x = img.to(torch.float32)
        x = x.clamp(0.0, 1.0)
        return _srgb_to_linear(x) if self.linearize else x

    def crop(self, img: torch.Tensor, generator: torch.Generator | int | None = None
             ) -> torch.Tensor:
        """A random ``image_size`` crop of ``(3, h, w)`` ``img`` (enlarged first if too small)."""
        H, W = self.image_size
        h, w = img.shape[-2:]
        if h < H or w < W:
            s = max(H / h, W / w)
            size = (max(H, math.ceil(h * s)), max(W, math.ceil(w * s)))
            img = F.interpolate(img[None], size=size, mode="bilinear", align_corners=False)[0]
            img = img.clamp(0.0, 1.0)
            h, w = size
        gen = None if generator is None else as_generator(generator)
        i = int(torch.randint(0, h - H + 1, (1,), generator=gen))
        j = int(torch.randint(0, w - W + 1, (1,), generator=gen))
        return img[:, i:i + H, j:j + W].contiguous()

    def sample(self, generator: torch.Generator | int) -> dict:
        """A random file and a random crop of it, both drawn from ``generator``."""
        gen = as_generator(generator)
        k = int(torch.randint(0, len(self.files), (1,), generator=gen))
        return {"image": self.crop(self.load(k), gen), "kind": "folder",
                "path": str(self.files[k])}

    def __getitem__(self, k: int) -> dict:
        k = int(k)
        if not -len(self.files) <= k < len(self.files):
            raise IndexError(f"ImageFolderDataset index {k} out of range for "
                             f"{len(self.files)} images in '{self.root}'")
        return {"image": self.crop(self.load(k)), "kind": "folder", "path": str(self.files[k])}


class CenterCropFolderDataset(Dataset):
    """A fixed test set from a folder of the user's own images: item ``k`` is the centre crop
    (``image_size``) of file ``k`` in sorted order, enlarged first if the image is smaller.
    Deterministic (no random crop), so every variant and seed sees the same pixels.

    Items: ``{"image": (3, H, W) float32 in [0, 1] (linear RGB), "kind": "folder", "path": str}``.

    Raises:
        FileNotFoundError: ``root`` missing, not a folder, or without images.
        RuntimeError: a file that cannot be decoded (named), raised when it is read.
    """

    def __init__(self, root: str | Path, image_size: Size, linearize: bool = True):
        self.folder = ImageFolderDataset(root, image_size, linearize)

    def __len__(self) -> int:
        return len(self.folder)

    def __getitem__(self, k: int) -> dict:
        k = int(k)
        if not 0 <= k < len(self):
            raise IndexError(f"CenterCropFolderDataset index {k} out of range for {len(self)} "
                             f"images in '{self.folder.root}'")
        img = self.folder.load(k)
        H, W = self.folder.image_size
        h, w = img.shape[-2:]
        if h < H or w < W:
            s = max(H / h, W / w)
            h, w = max(H, math.ceil(h * s)), max(W, math.ceil(w * s))
            img = F.interpolate(img[None], size=(h, w), mode="bilinear",
                                align_corners=False)[0].clamp(0.0, 1.0)
        i, j = (h - H) // 2, (w - W) // 2
        return {"image": img[:, i:i + H, j:j + W].contiguous(), "kind": "folder",
                "path": str(self.folder.files[k])}


class _FolderStream(_SeededStream):
    """Training stream of random crops of an :class:`ImageFolderDataset` (seeded like textures)."""

    def __init__(self, folder: ImageFolderDataset, seed: int = 0,
                 samples_per_epoch: int | None = None, chunk_size: int = 1):
        super().__init__(seed, samples_per_epoch, chunk_size)
        self.folder = folder

    def make_item(self, seed: int) -> dict:
        return self.folder.sample(seed)


class EpochLoader(DataLoader):
    """A :class:`~torch.utils.data.DataLoader` calling ``dataset.set_epoch(e)`` before pass ``e``.

    The epoch of a pass is ``epoch_fn()`` when given, read when the pass starts (the data module
    passes the trainer's current epoch: a resumed run knows its epoch only once Lightning has
    restored its loops, after the loader was built); otherwise passes are counted from
    ``start_epoch`` (0, 1, 2, ... by default).  So a seeded stream gives new, reproducible items
    every epoch.  Workers must not be persistent (they would keep the dataset of the epoch they
    started with).
    """

    def __init__(self, dataset, *args, start_epoch: int = 0, epoch_fn=None, progress_fn=None,
                 **kwargs):
        super().__init__(dataset, *args, **kwargs)
        if self.persistent_workers and self.num_workers > 0:
            raise ValueError("EpochLoader: persistent_workers=True would keep every worker on "
                             "the first epoch's stream; leave it False")
        self.start_epoch = _check_int("start_epoch", start_epoch, 0)
        self.epoch = self.start_epoch
        self.epoch_fn = epoch_fn
        self.progress_fn = progress_fn
        self._pass_epoch: int | None = None  # epoch of the pass under way
        self._resume: tuple[int, int] | None = None  # (epoch, batches done) from a checkpoint

    def state_dict(self) -> dict:
        """``{"epoch", "batches"}``: the pass's epoch and the batches of it the training loop
        has processed (``progress_fn()``; Lightning stores this in every checkpoint)."""
        done = 0 if self.progress_fn is None else int(self.progress_fn())
        epoch = self.epoch if self._pass_epoch is None else self._pass_epoch
        return {"epoch": int(epoch), "batches": done}

    def load_state_dict(self, state: dict) -> None:
        """Start the next pass of ``state["epoch"]`` after its first ``state["batches"]``."""
        self._resume = (_check_int("epoch", state["epoch"], 0),
                        _check_int("batches", state["batches"], 0))

    def __iter__(self):
        if self.epoch_fn is not None:
            self.epoch = _check_int("epoch_fn()", self.epoch_fn(), 0)
        start = 0
        if self._resume is not None:
            epoch, batches = self._resume
            self._resume = None
            try:
                n = len(self)
            except TypeError:  # an endless stream
                n = None
            if epoch == self.epoch and (n is None or batches < n):
                start = batches * (self.batch_size or 1)
        if callable(getattr(self.dataset, "set_epoch", None)):
            if start:
                self.dataset.set_epoch(self.epoch, start=start)
            else:
                self.dataset.set_epoch(self.epoch)
        elif start:
            raise ValueError(f"EpochLoader: cannot resume {type(self.dataset).__name__} at "
                             f"batch {start // (self.batch_size or 1)} (no set_epoch(start=))")
        self._pass_epoch = self.epoch
        self.epoch += 1
        return super().__iter__()


class TextureDataModule(L.LightningDataModule):
    """Procedural (or own-folder) training data, fixed procedural validation and test sets.

    Args:
        image_size: ``int`` or ``(H, W)`` pixels of every image.
        batch_size: images per batch (all loaders).
        train_steps_per_epoch: training batches per epoch (the stream has
            ``train_steps_per_epoch * batch_size`` items per epoch, new ones each epoch).
        val_size: validation images (fixed by ``seed``).
        test_size: test images (fixed by ``seed``, disjoint from validation).
        seed: the one seed of everything (>= 0).
        kinds: texture kinds, default all (see :data:`~deeplens.data.textures.TEXTURES`).
        num_workers: DataLoader worker processes (0: load in the main process).
        image_folder: if given, train on random crops of these images instead of textures
            (validation and test stay procedural, so they are comparable across runs).
        test_folder: if given, the test set is the centre crops of these images (every file,
            sorted by path) instead of procedural textures; ``test_size`` is then ignored.

    Raises:
        ValueError: an argument out of range (the message names it and the value).
        FileNotFoundError: ``image_folder`` or ``test_folder`` missing or without images.
    """

    def __init__(self, image_size: Size = 256, batch_size: int = 8,
                 train_steps_per_epoch: int = 1000, val_size: int = 64, test_size: int = 64,
                 seed: int = 0, kinds: str | Sequence[str] | None = None, num_workers: int = 0,
                 image_folder: str | Path | None = None, test_folder: str | Path | None = None):
        super().__init__()
        self.image_size = parse_size(image_size, "image_size")
        self.batch_size = _check_int("batch_size", batch_size, 1)
        self.train_steps_per_epoch = _check_int("train_steps_per_epoch", train_steps_per_epoch, 1)
        self.val_size = _check_int("val_size", val_size, 1)
        self.test_size = _check_int("test_size", test_size, 1)
        self.seed = _check_int("seed", seed, 0)
        self.kinds = check_kinds(kinds)
        self.num_workers = _check_int("num_workers", num_workers, 0)
        self.image_folder = None if image_folder is None else Path(image_folder)
        self._folder = (None if self.image_folder is None
                        else ImageFolderDataset(self.image_folder, self.image_size))
        self.test_folder = None if test_folder is None else Path(test_folder)
        self._test_folder = (None if self.test_folder is None
                             else CenterCropFolderDataset(self.test_folder, self.image_size))
        self.save_hyperparameters({
            "image_size": list(self.image_size), "batch_size": self.batch_size,
            "train_steps_per_epoch": self.train_steps_per_epoch, "val_size": self.val_size,
            "test_size": self.test_size, "seed": self.seed, "kinds": list(self.kinds),
            "num_workers": self.num_workers,
            "image_folder": None if image_folder is None else str(image_folder),
            "test_folder": None if test_folder is None else str(test_folder)})
        self.train_set: _SeededStream | None = None
        self.val_set: TextureDataset | None = None
        self.test_set: TextureDataset | CenterCropFolderDataset | None = None

    @property
    def val_base_seed(self) -> int:
        return derive_seed(self.seed, "val")

    @property
    def test_base_seed(self) -> int:
        return self.val_base_seed + self.val_size

    def setup(self, stage: str | None = None) -> None:
        n = self.train_steps_per_epoch * self.batch_size
        if self._folder is not None:
            self.train_set = _FolderStream(self._folder, self.seed, n, self.batch_size)
        else:
            self.train_set = EndlessTextureDataset(self.image_size, self.seed, self.kinds, n,
                                                   self.batch_size)
        self.val_set = TextureDataset(self.val_size, self.image_size, self.val_base_seed,
                                      self.kinds)
        self.test_set = (self._test_folder if self._test_folder is not None else
                         TextureDataset(self.test_size, self.image_size, self.test_base_seed,
                                        self.kinds))

    def _ensure_setup(self) -> None:
        if self.train_set is None:
            self.setup()

    def train_dataloader(self) -> EpochLoader:
        self._ensure_setup()
        trainer = getattr(self, "trainer", None)
        # The epoch is read when each pass starts, and from the loop's count of processed
        # epochs: on resume Lightning builds this loader and starts its first pass before it
        # brings ``current_epoch`` up to date (a run resumed after epoch 0 would replay epoch
        # 0's items); ``processed`` is what Lightning itself gives samplers' ``set_epoch``.
        epoch_fn = None if trainer is None else (
            lambda: int(trainer.fit_loop.epoch_progress.current.processed))
        # batches of this pass whose training step ran: what a checkpoint saved now has seen
        progress_fn = None if trainer is None else (
            lambda: int(trainer.fit_loop.epoch_loop.batch_progress.current.processed))
        return EpochLoader(self.train_set, batch_size=self.batch_size,
                           num_workers=self.num_workers, epoch_fn=epoch_fn,
                           progress_fn=progress_fn)

    def _fixed_loader(self, dataset: Dataset) -> DataLoader:
        return DataLoader(dataset, batch_size=self.batch_size, shuffle=False,
                          num_workers=self.num_workers)

    def val_dataloader(self) -> DataLoader:
        self._ensure_setup()
        return self._fixed_loader(self.val_set)

    def test_dataloader(self) -> DataLoader:
        self._ensure_setup()
        return self._fixed_loader(self.test_set)
