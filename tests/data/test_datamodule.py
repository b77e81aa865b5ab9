"""Datasets, training streams, the image-folder dataset and the Lightning data module."""

from __future__ import annotations

import itertools

import pytest
import torch
from torch.utils.data import DataLoader

from deeplens.data import (
    EndlessTextureDataset,
    EpochLoader,
    ImageFolderDataset,
    TextureDataModule,
    TextureDataset,
)
from deeplens.data.datamodule import derive_seed
from deeplens.data.textures import random_texture

torchvision_io = pytest.importorskip("torchvision.io")


def _images(loader, n_batches=None):
    batches = loader if n_batches is None else itertools.islice(loader, n_batches)
    return torch.cat([b["image"] for b in batches])


def _all_distinct(images):
    flat = images.reshape(images.shape[0], -1)
    return all(not torch.equal(flat[i], flat[j])
               for i in range(len(flat)) for j in range(i + 1, len(flat)))


# --------------------------------------------------------------------------- seeds, fixed sets

def test_derive_seed():
    assert derive_seed(1, 2, 3) == derive_seed(1, 2, 3)
    seeds = {derive_seed(0, e, i) for e in range(3) for i in range(100)}
    assert len(seeds) == 300
    assert all(0 <= s < 2 ** 62 for s in seeds)
    assert derive_seed(0, "val") != derive_seed(0, "test") != derive_seed(1, "val")
    assert len({derive_seed(v) for v in (-1, 1, 2 ** 64 - 1, 2 ** 64, "a", 97, "")}) == 7
    assert derive_seed(1, 23) != derive_seed(12, 3)
    with pytest.raises(TypeError):
        derive_seed(1.5)


def test_texture_dataset_items_are_fixed_by_seed():
    ds = TextureDataset(5, (24, 32), base_seed=100)
    assert len(ds) == 5
    item = ds[3]
    assert set(item) == {"image", "kind", "seed"}
    assert item["image"].shape == (3, 24, 32) and item["image"].dtype == torch.float32
    assert item["seed"] == 103
    ref, kind = random_texture((24, 32), 103)
    assert torch.equal(item["image"], ref) and item["kind"] == kind
    # independent of order and instance
    again = TextureDataset(5, (24, 32), base_seed=100)
    assert all(torch.equal(again[k]["image"], ds[k]["image"]) for k in (4, 0, 3))
    assert torch.equal(ds[-1]["image"], ds[4]["image"])
    assert not torch.equal(TextureDataset(5, (24, 32), base_seed=101)[3]["image"], item["image"])
    with pytest.raises(IndexError):
        ds[5]


def test_texture_dataset_same_through_workers():
    ds = TextureDataset(6, 16, base_seed=7)
    direct = torch.stack([ds[k]["image"] for k in range(6)])
    loaded = _images(DataLoader(ds, batch_size=4, num_workers=2))
    assert torch.equal(direct, loaded)


# --------------------------------------------------------------------------- training stream

def test_endless_stream_seeded_and_per_epoch():
    def first(seed, epoch, n=4):
        ds = EndlessTextureDataset(24, seed=seed)
        ds.set_epoch(epoch)
        return torch.stack([it["image"] for it in itertools.islice(iter(ds), n)])

    a = first(1, 0)
    assert torch.equal(a, first(1, 0))                   # reproducible
    assert not torch.equal(a, first(2, 0))               # seed matters
    b = first(1, 1)
    assert not any(torch.equal(a[i], b[j]) for i in range(4) for j in range(4))   # new epoch
    assert _all_distinct(a)
    with pytest.raises(TypeError, match="endless"):
        len(EndlessTextureDataset(8))


def test_stream_epoch_length_and_kinds():
    ds = EndlessTextureDataset(12, seed=0, kinds=["grating", "checkerboard"],
                               samples_per_epoch=7, chunk_size=3)
    items = list(ds)
    assert len(ds) == 7 and len(items) == 7
    assert {it["kind"] for it in items} <= {"grating", "checkerboard"}


def test_stream_differs_across_workers_and_matches_single_process():
    def first_batches(num_workers):
        ds = EndlessTextureDataset(16, seed=5, chunk_size=2)          # endless
        loader = EpochLoader(ds, batch_size=2, num_workers=num_workers)
        return list(itertools.islice(iter(loader), 4))

    batches = first_batches(2)             # batches 0, 2 come from worker 0; 1, 3 from worker 1
    images = torch.cat([b["image"] for b in batches])
    assert _all_distinct(images)                         # workers do not repeat each other
    single = first_batches(0)
    assert torch.equal(torch.cat([b["seed"] for b in batches]),
                       torch.cat([b["seed"] for b in single]))   # same stream, same order
    assert torch.equal(images, torch.cat([b["image"] for b in single]))


def test_epoch_loader_new_items_each_pass_reproducibly():
    def loader(start=0):
        ds = EndlessTextureDataset(16, seed=3, samples_per_epoch=6, chunk_size=3)
        return EpochLoader(ds, batch_size=3, start_epoch=start)

    ld = loader()
    assert len(ld) == 2
    e0, e1 = _images(ld), _images(ld)
    assert e0.shape == (6, 3, 16, 16)
    assert not any(torch.equal(x, y) for x in e0 for y in e1)
    assert torch.equal(e1, _images(loader(start=1)))     # resuming at epoch 1 reproduces it
    with pytest.raises(ValueError, match="persistent_workers"):
        EpochLoader(EndlessTextureDataset(8, samples_per_epoch=2), batch_size=1,
                    num_workers=1, persistent_workers=True)


# --------------------------------------------------------------------------- image folder

def _write_png(path, img_uint8):
    torchvision_io.write_png(img_uint8, str(path))


@pytest.fixture
def image_dir(tmp_path):
    g = torch.Generator().manual_seed(0)
    _write_png(tmp_path / "a.png", torch.randint(0, 256, (3, 40, 50), dtype=torch.uint8,
                                                 generator=g))
    _write_png(tmp_path / "b.PNG", torch.full((1, 20, 12), 128, dtype=torch.uint8))  # grey, small
    sub = tmp_path / "sub"
    sub.mkdir()
    torchvision_io.write_jpeg(torch.randint(0, 256, (3, 64, 64), dtype=torch.uint8, generator=g),
                              str(sub / "c.jpg"))
    (tmp_path / "notes.txt").write_text("not an image")
    return tmp_path


def test_image_folder_dataset(image_dir):
    ds = ImageFolderDataset(image_dir, 32)
    assert [p.name for p in ds.files] == ["a.png", "b.PNG", "c.jpg"]
    for k in range(len(ds)):
        item = ds[k]
        x = item["image"]
        assert x.shape == (3, 32, 32) and x.dtype == torch.float32
        assert float(x.min()) >= 0 and float(x.max()) <= 1
        assert item["kind"] == "folder"
    # the small grey image is enlarged and decoded from sRGB: 128/255 -> ~0.2158 linear
    grey = ds[1]["image"]
    assert torch.allclose(grey, torch.full_like(grey, 0.21586), atol=1e-3)
    raw = ImageFolderDataset(image_dir, 8, linearize=False).load(1)
    assert raw.shape == (3, 20, 12) and torch.allclose(raw, torch.full_like(raw, 128 / 255))
    # seeded sampling is reproducible, crops come from the image
    a, b = ds.sample(3), ds.sample(3)
    assert a["path"] == b["path"] and torch.equal(a["image"], b["image"])
    full = ds.load(0)
    crop = ds.crop(full, 1)
    found = any(torch.equal(crop, full[:, i:i + 32, j:j + 32])
                for i in range(full.shape[1] - 31) for j in range(full.shape[2] - 31))
    assert found


def test_image_folder_16bit_and_corrupt_files(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    import numpy as np

    ramp = (np.arange(20 * 30).reshape(20, 30) * 100).astype(np.uint16)   # up to 59900
    Image.fromarray(ramp).save(tmp_path / "deep.png")
    ds = ImageFolderDataset(tmp_path, 8, linearize=False)
    x = ds.load(0)
    assert x.shape == (3, 20, 30)
    assert float(x.max()) == pytest.approx(59900 / 65535, abs=1e-6)       # 16-bit scale
    (tmp_path / "zz_bad.png").write_bytes(b"this is not a png")
    with pytest.raises(RuntimeError, match="zz_bad.png"):
        ImageFolderDataset(tmp_path, 8).load(1)


def test_image_folder_errors_name_the_folder(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("x")
    with pytest.raises(FileNotFoundError, match="empty.*contains no images"):
        ImageFolderDataset(empty, 16)
    with pytest.raises(FileNotFoundError, match="missing.*does not exist"):
        ImageFolderDataset(tmp_path / "missing", 16)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        TextureDataModule(image_size=16, image_folder=tmp_path / "missing")


# --------------------------------------------------------------------------- data module

def _dm(**kw):
    args = dict(image_size=24, batch_size=4, train_steps_per_epoch=3, val_size=6, test_size=5,
                seed=11)
    args.update(kw)
    return TextureDataModule(**args)


def test_datamodule_loaders_shapes():
    dm = _dm()
    dm.setup("fit")
    train = dm.train_dataloader()
    batches = list(train)
    assert len(batches) == len(train) == 3
    for b in batches:
        assert b["image"].shape == (4, 3, 24, 24) and b["image"].dtype == torch.float32
        assert len(b["kind"]) == 4
    val = list(dm.val_dataloader())
    assert [b["image"].shape[0] for b in val] == [4, 2]
    test = list(dm.test_dataloader())
    assert [b["image"].shape[0] for b in test] == [4, 1]
    rect = _dm(image_size=(16, 20), batch_size=2)
    assert next(iter(rect.val_dataloader()))["image"].shape == (2, 3, 16, 20)


def test_datamodule_val_test_fixed_disjoint_and_train_changes():
    a, b = _dm(), _dm()
    val_a, val_b = _images(a.val_dataloader()), _images(b.val_dataloader())
    assert torch.equal(val_a, val_b)                     # fixed by the seed
    test_a = _images(a.test_dataloader())
    assert torch.equal(test_a, _images(b.test_dataloader()))
    seeds_val = {s for bt in a.val_dataloader() for s in bt["seed"].tolist()}
    seeds_test = {s for bt in a.test_dataloader() for s in bt["seed"].tolist()}
    assert a.val_base_seed != a.test_base_seed and not seeds_val & seeds_test
    assert not any(torch.equal(v, t) for v in val_a for t in test_a)
    assert not torch.equal(val_a, _images(_dm(seed=12).val_dataloader()))
    # training: new images each epoch, reproducible given the seed, never a validation seed
    ta, tb = a.train_dataloader(), b.train_dataloader()
    e0a, e1a = _images(ta), _images(ta)
    assert torch.equal(e0a, _images(tb)) and not torch.equal(e0a, e1a)
    train_seeds = {s for bt in a.train_dataloader() for s in bt["seed"].tolist()}
    assert not train_seeds & (seeds_val | seeds_test)


def test_datamodule_folder_training(image_dir):
    dm = _dm(image_folder=image_dir, image_size=16)
    b = next(iter(dm.train_dataloader()))
    assert b["image"].shape == (4, 3, 16, 16) and b["kind"] == ["folder"] * 4
    assert next(iter(dm.val_dataloader()))["kind"][0] != "folder"   # validation is procedural


@pytest.mark.parametrize("kw, message", [
    (dict(image_size=-3), "image_size must be a positive int or a pair of positive ints "
                          r"\(H, W\), got -3"),
    (dict(image_size=(16, 0)), "image_size"),
    (dict(batch_size=0), "batch_size must be a positive int, got 0"),
    (dict(batch_size=2.5), "batch_size"),
    (dict(train_steps_per_epoch=True), "train_steps_per_epoch"),
    (dict(val_size=0), "val_size must be a positive int, got 0"),
    (dict(test_size=-1), "test_size"),
    (dict(seed=-1), r"seed must be an int >= 0, got -1"),
    (dict(num_workers=-2), "num_workers must be an int >= 0, got -2"),
    (dict(kinds=["dead_leaves", "plasma"]), "unknown texture kind"),
    (dict(kinds=[]), "at least one"),
])
def test_datamodule_argument_validation(kw, message):
    with pytest.raises(ValueError, match=message):
        _dm(**kw)


def test_datamodule_with_lightning_trainer():
    """Under a Trainer, each epoch gets new training images and validation stays fixed."""
    L = pytest.importorskip("lightning")

    class Recorder(L.LightningModule):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(()))
            self.train_seeds, self.val_seeds = {}, {}

        def training_step(self, batch, _):
            self.train_seeds.setdefault(self.current_epoch, []).extend(batch["seed"].tolist())
            return (self.w - batch["image"].mean()) ** 2

        def validation_step(self, batch, _):
            self.val_seeds.setdefault(self.current_epoch, []).extend(batch["seed"].tolist())

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.1)

    model = Recorder()
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=_dm(image_size=16, train_steps_per_epoch=2, val_size=3))
    assert [len(model.train_seeds[e]) for e in (0, 1)] == [8, 8]
    assert not set(model.train_seeds[0]) & set(model.train_seeds[1])
    assert model.val_seeds[0] == model.val_seeds[1]
