"""Tests for the restoration networks, the PatchGAN discriminator and the losses in
``deeplens.nets`` (CPU, small sizes, no downloads)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from deeplens.nets import (
    FPNGenerator,
    PatchGANDiscriminator,
    PerceptualLoss,
    UNet,
    adversarial_loss,
    count_parameters,
    relativistic_adversarial_loss,
)

@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """These tests are many tiny convolutions: one intra-op thread is as fast, and far more
    robust on a shared/loaded CPU than a spinning thread pool."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


# small configurations that keep the training-style tests fast
SMALL = {
    "unet": lambda **kw: UNet(base_channels=8, depth=3, **kw),
    "fpn": lambda **kw: FPNGenerator(base_channels=8, fpn_channels=16, num_levels=3, **kw),
}


# --------------------------------------------------------------------------------------------
# generators: shapes and the identity at initialisation
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make", [
    lambda: UNet(),
    lambda: UNet(depth=2, norm="instance"),
    lambda: UNet(base_channels=8, depth=5, norm="none"),
    lambda: FPNGenerator(),
    lambda: FPNGenerator(num_levels=2, norm="batch"),
    lambda: FPNGenerator(base_channels=8, fpn_channels=16, num_levels=5, norm="none"),
], ids=["unet", "unet-d2-inst", "unet-d5-none", "fpn", "fpn-l2-batch", "fpn-l5-none"])
@pytest.mark.parametrize("hw", [(37, 53), (5, 7)])
def test_generator_output_shape_any_size(make, hw):
    net = make()
    x = torch.rand(2, 3, *hw)
    y = net(x)
    assert y.shape == x.shape
    assert torch.isfinite(y).all()


@pytest.mark.parametrize("cls", [UNet, FPNGenerator])
def test_non_residual_channel_change(cls):
    net = cls(in_channels=3, out_channels=1, residual=False, zero_init_head=False)
    y = net(torch.rand(1, 3, 37, 53))
    assert y.shape == (1, 1, 37, 53)
    with pytest.raises(ValueError, match="in_channels == out_channels"):
        cls(in_channels=3, out_channels=1, residual=True)
    with pytest.raises(ValueError, match="norm"):
        cls(norm="group")


@pytest.mark.parametrize("make", [
    lambda: UNet(), lambda: UNet(norm="instance"), lambda: FPNGenerator(),
    lambda: FPNGenerator(norm="batch", clamp_range=(0.0, 1.0)),
], ids=["unet-batch", "unet-instance", "fpn-instance", "fpn-batch-clamp01"])
@pytest.mark.parametrize("train", [True, False])
def test_residual_generator_is_identity_at_init(make, train):
    """Promise: residual=True with the default zero-initialised head returns the input exactly
    (train and eval mode; with clamp_range=(0, 1) for inputs inside the range)."""
    net = make().train(train)
    x = torch.rand(2, 3, 37, 53)
    with torch.no_grad():
        y = net(x)
    assert torch.equal(y, x)


def test_fpn_clamp_and_tanh_bound():
    """FPN output = clamp(x + tanh(.)): the correction is bounded by 1 and the clamp holds."""
    net = FPNGenerator(base_channels=8, fpn_channels=16, num_levels=3, zero_init_head=False)
    torch.nn.init.normal_(net.final.weight, std=5.0)
    x = torch.rand(1, 3, 33, 40)
    with torch.no_grad():
        y = net(x)
        assert (y - x).abs().max() <= 1.0
        assert (y - x).abs().max() > 0.1
        net.clamp_range = (0.0, 1.0)
        yc = net(x)
    assert yc.min() >= 0.0 and yc.max() <= 1.0
    assert torch.equal(yc, y.clamp(0.0, 1.0))


# --------------------------------------------------------------------------------------------
# parameters and gradients
# --------------------------------------------------------------------------------------------
def test_parameter_counts_scale_with_width():
    u16, u32 = count_parameters(UNet(base_channels=16)), count_parameters(UNet(base_channels=32))
    f16 = count_parameters(FPNGenerator(base_channels=16, fpn_channels=32))
    f32 = count_parameters(FPNGenerator(base_channels=32, fpn_channels=64))
    # conv weights are quadratic in the width: doubling it gives ~4x the parameters
    assert 3.5 < u32 / u16 < 4.05
    assert 3.5 < f32 / f16 < 4.05
    # depth adds parameters too
    assert count_parameters(UNet(depth=3)) < count_parameters(UNet(depth=4))
    assert count_parameters(FPNGenerator(num_levels=3)) < count_parameters(FPNGenerator(num_levels=4))


@pytest.mark.parametrize("name,norm", [("unet", "batch"), ("unet", "instance"), ("unet", "none"),
                                       ("fpn", "instance"), ("fpn", "batch"), ("fpn", "none")])
def test_gradients_reach_every_parameter(name, norm):
    net = SMALL[name](norm=norm)
    x = torch.rand(2, 3, 29, 35)
    target = torch.rand(2, 3, 29, 35)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)

    def loss_fn():
        return ((net(x) - target) ** 2).mean()

    # step 0: the zero-initialised head is the only layer with a gradient (by design)
    loss_fn().backward()
    head = net.head if name == "unet" else net.final
    assert head.weight.grad.abs().sum() > 0
    opt.step()
    opt.zero_grad()
    # after one step the head is non-zero and every parameter receives a gradient
    loss_fn().backward()
    for pname, p in net.named_parameters():
        assert p.grad is not None, pname
        assert torch.isfinite(p.grad).all(), pname
        assert p.grad.abs().sum() > 0, f"zero gradient for {pname}"


def _blurred_pair(hw=24, batch=1):
    """A random piecewise-constant 'sharp' image (4x4-pixel cells) and its Gaussian blur."""
    g = torch.Generator().manual_seed(1)
    coarse = torch.rand(batch, 3, hw // 4, hw // 4, generator=g)
    sharp = F.interpolate(coarse, size=(hw, hw), mode="nearest")          # piecewise constant
    k = torch.arange(-3, 4, dtype=torch.float32)
    k = torch.exp(-0.5 * (k / 1.5) ** 2)
    k2 = (k[:, None] * k[None, :]) / k.sum() ** 2
    w = k2.expand(3, 1, 7, 7).contiguous()
    blurred = F.conv2d(F.pad(sharp, (3, 3, 3, 3), mode="replicate"), w, groups=3)
    return blurred, sharp


@pytest.mark.parametrize("name", ["unet", "fpn"])
def test_overfit_blurred_to_sharp(name):
    net = SMALL[name]()
    blurred, sharp = _blurred_pair()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    with torch.no_grad():
        l1_0 = F.l1_loss(net(blurred), sharp).item()
    assert l1_0 == pytest.approx(F.l1_loss(blurred, sharp).item())    # identity at init
    for _ in range(40):
        opt.zero_grad()
        loss = F.l1_loss(net(blurred), sharp)
        loss.backward()
        opt.step()
    with torch.no_grad():                         # same (train) mode as optimised
        l1 = F.l1_loss(net(blurred), sharp).item()
    assert l1 < 0.7 * l1_0, (l1_0, l1)       # observed ~0.45x after 40 steps


# --------------------------------------------------------------------------------------------
# discriminator
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("hw,n_layers,expected", [
    ((256, 256), 3, (30, 30)),         # the pix2pix 70x70 PatchGAN on 256x256 crops
    ((128, 128), 3, (14, 14)),
    ((37, 53), 3, (2, 4)),             # 37->18->9->4->2 ; 53->26->13->6->4
    ((64, 96), 2, (14, 22)),
])
def test_discriminator_patch_map_size(hw, n_layers, expected):
    d = PatchGANDiscriminator(n_layers=n_layers)
    out = d(torch.rand(2, 3, *hw))
    assert out.shape == (2, 1, *expected)
    assert d.output_size(*hw) == expected


def test_discriminator_receptive_field_is_70():
    d = PatchGANDiscriminator(base_channels=8, norm="none").double()
    assert d.receptive_field() == 70
    x = torch.rand(1, 3, 128, 128, dtype=torch.float64, requires_grad=True)
    out = d(x)
    out[0, 0, 7, 7].backward()
    support = x.grad.abs().sum(dim=(0, 1)) > 0
    rows = torch.nonzero(support.any(dim=1)).flatten()
    cols = torch.nonzero(support.any(dim=0)).flatten()
    assert rows.max() - rows.min() + 1 == 70
    assert cols.max() - cols.min() + 1 == 70


# --------------------------------------------------------------------------------------------
# adversarial losses
# --------------------------------------------------------------------------------------------
def test_adversarial_loss_known_values():
    logits = torch.tensor([0.5, 2.0])
    assert adversarial_loss(logits, True).item() == pytest.approx((0.25 + 1.0) / 2)     # lsgan
    assert adversarial_loss(logits, False).item() == pytest.approx((0.25 + 4.0) / 2)
    sp = lambda v: math.log1p(math.exp(v))  # noqa: E731  softplus
    assert adversarial_loss(logits, True, "bce").item() == pytest.approx((sp(-0.5) + sp(-2.0)) / 2)
    assert adversarial_loss(logits, False, "bce").item() == pytest.approx((sp(0.5) + sp(2.0)) / 2)
    assert adversarial_loss(torch.zeros(3, 1, 4, 4), True, "bce").item() == pytest.approx(math.log(2))
    # perfect LSGAN discriminator: zero loss
    assert adversarial_loss(torch.ones(2, 1, 5, 5), True).item() == 0.0
    assert adversarial_loss(torch.zeros(2, 1, 5, 5), False).item() == 0.0
    with pytest.raises(ValueError):
        adversarial_loss(logits, True, kind="wgan")


def test_adversarial_loss_gradient_direction():
    logits = torch.tensor([0.3, 0.7], requires_grad=True)      # inside (0, 1): both targets pull
    for kind in ("lsgan", "bce"):
        (g,) = torch.autograd.grad(adversarial_loss(logits, True, kind), logits)
        assert (g < 0).all()           # minimising "real" pushes logits up
        (g,) = torch.autograd.grad(adversarial_loss(logits, False, kind), logits)
        assert (g > 0).all()           # minimising "fake" pushes them down


def test_relativistic_loss_known_values():
    real, fake = torch.tensor([1.0, 3.0]), torch.tensor([0.0, 2.0])
    # Dr = real - mean(fake) = [0, 2] ; Df = fake - mean(real) = [-2, 0]
    d = relativistic_adversarial_loss(real, fake, for_discriminator=True)
    g = relativistic_adversarial_loss(real, fake, for_discriminator=False)
    assert d.item() == pytest.approx(0.5 * ((1 + 1) / 2 + (4 + 0) / 2))
    assert g.item() == pytest.approx(0.5 * ((9 + 1) / 2 + (0 + 4) / 2))
    sp = lambda v: math.log1p(math.exp(v))  # noqa: E731
    db = relativistic_adversarial_loss(real, fake, True, kind="bce")
    assert db.item() == pytest.approx(0.5 * ((sp(-0.0) + sp(-2.0)) / 2 + (sp(-2.0) + sp(0.0)) / 2))


# --------------------------------------------------------------------------------------------
# perceptual loss
# --------------------------------------------------------------------------------------------
def test_perceptual_loss_missing_weights_fails_fast(tmp_path, monkeypatch):
    def _no_download(*a, **k):
        raise AssertionError("PerceptualLoss tried to download")

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", _no_download)
    monkeypatch.setattr(torch.hub, "download_url_to_file", _no_download)
    missing = tmp_path / "nope" / "vgg16.pth"
    with pytest.raises(FileNotFoundError) as exc:
        PerceptualLoss(weights_path=missing)
    msg = str(exc.value)
    assert str(missing) in msg and "weights_path" in msg and "vgg16-397923af.pth" in msg

    # default lookup: env var, then the torch hub cache (redirected to tmp via TORCH_HOME)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    monkeypatch.setenv("DEEPLENS_VGG16_WEIGHTS", str(tmp_path / "env.pth"))
    with pytest.raises(FileNotFoundError) as exc:
        PerceptualLoss()
    msg = str(exc.value)
    assert str(tmp_path / "env.pth") in msg
    assert str(tmp_path / "torch_home" / "hub" / "checkpoints" / "vgg16-397923af.pth") in msg


@pytest.fixture(scope="module")
def random_vgg16_weights(tmp_path_factory):
    """A randomly initialised torchvision VGG16 state dict saved to disk (features.* keys only,
    plus one stray classifier key: the loader must ignore the classifier)."""
    import torchvision

    torch.manual_seed(0)
    sd = torchvision.models.vgg16(weights=None).state_dict()
    sd = {k: v for k, v in sd.items() if k.startswith("features.")}
    sd["classifier.6.bias"] = torch.zeros(1000)
    path = tmp_path_factory.mktemp("vgg") / "vgg16-random.pth"
    torch.save(sd, path)
    return path


def test_perceptual_loss_with_local_weights(random_vgg16_weights):
    loss = PerceptualLoss(layers=("relu1_2", "relu2_2", "relu3_3"), weights_path=random_vgg16_weights)
    # loaded values, not the meta/random construction
    ref = torch.load(random_vgg16_weights, weights_only=True)
    assert torch.equal(loss.features[0].weight, ref["features.0.weight"])
    assert all(not p.requires_grad for p in loss.parameters())
    assert len(loss.features) == 16          # truncated after relu3_3

    g = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 40, 48, generator=g)
    b = torch.rand(2, 3, 40, 48, generator=g)
    assert loss(a, a.clone()).item() == 0.0
    pred = a.clone().requires_grad_(True)
    val = loss(pred, b)
    assert val.item() > 0
    val.backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all()
    assert pred.grad.abs().sum() > 0
    # stays in eval mode under .train() and is symmetric
    loss.train()
    assert not loss.features.training
    assert loss(b, a).item() == pytest.approx(val.item(), rel=1e-5)


def test_perceptual_loss_options(random_vgg16_weights, monkeypatch):
    monkeypatch.setenv("DEEPLENS_VGG16_WEIGHTS", str(random_vgg16_weights))
    l1 = PerceptualLoss(layers="conv2_2", distance="l1")            # found through the env var
    assert l1.weights_path == random_vgg16_weights
    a, b = torch.rand(1, 3, 24, 24), torch.rand(1, 3, 24, 24)
    assert l1(a, b).item() > 0
    # input_range: [-1, 1] images give the same features as their [0, 1] counterparts
    lm = PerceptualLoss(input_range=(-1.0, 1.0), weights_path=random_vgg16_weights)
    l0 = PerceptualLoss(weights_path=random_vgg16_weights)
    assert lm(2 * a - 1, 2 * b - 1).item() == pytest.approx(l0(a, b).item(), rel=1e-5)
    with pytest.raises(ValueError, match="unknown VGG16 layer"):
        PerceptualLoss(layers=("relu9_9",), weights_path=random_vgg16_weights)
