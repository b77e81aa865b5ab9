"""An image through a lens: a picture as a plane at one depth, rendered onto a sensor.

The picture fills the ideal camera's field of view at ``depth_mm`` (:class:`~.scene.Scene`
with no size: a distortion-free pinhole at the entrance pupil with the lens's framing, so a
perfect lens reproduces the picture pixel for pixel) and is rendered by backward Monte Carlo
(:class:`~.monte_carlo.MonteCarloRenderer`, relative illumination on) on a sensor of the
picture's own resolution whose diagonal is the lens's image circle (``2 ×`` the sensor
semi-diameter of the lens file) unless a pixel pitch is given.  Each colour channel is traced
at its own wavelength (R, G, B = 656.3, 587.6, 486.1 nm); a grey picture at 587.6 nm.

Picture files hold sRGB-encoded values; the scene is linear radiance, so files are decoded
(``srgb_to_linear``) on reading and encoded again on writing (``linear=True`` skips both).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..optics.camera import unpack
from .monte_carlo import MonteCarloRenderer
from .scene import Scene
from .sensor import RGB_WAVELENGTHS_NM, Sensor

__all__ = ["render_image", "read_image", "write_image", "srgb_to_linear", "linear_to_srgb",
           "default_pixel_size"]


def srgb_to_linear(v: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 decoding of values in ``[0, 1]``."""
    return torch.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 encoding of values in ``[0, 1]`` (clamped first)."""
    v = v.clamp(0, 1)
    return torch.where(v <= 0.0031308, 12.92 * v, 1.055 * v.clamp(min=1e-12) ** (1 / 2.4) - 0.055)


def read_image(path, max_side: int | None = None, linear: bool = False) -> torch.Tensor:
    """A picture file as ``(C, H, W)`` float64 in ``[0, 1]`` (C = 1 or 3; alpha dropped),
    down-sampled (area average) so that its longer side is at most ``max_side`` pixels.

    8-bit pictures are divided by 255.  Greyscale pictures of more than 8 bits are read at full
    precision, each scaled by its type's range: 16-bit (Pillow modes ``I;16*``) by 65535, 32-bit
    integer (mode ``I``, e.g. a 16-bit picture Pillow decodes as such) by 65535 when its values
    fit in 16 bits (else refused), 32-bit float (mode ``F``) as it is (its range is [0, 1];
    values outside are clipped, NaN or infinity refused).  (Pillow decodes 16-bit colour PNGs to
    8 bits per channel.)

    Raises:
        FileNotFoundError: no such file.  ValueError: not a readable image, or one larger than
            Pillow's decompression-bomb limit (names the file, its size and the limit).
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    try:
        with Image.open(path) as im:
            if im.mode in _HIGH_DEPTH:
                img = _read_high_depth(im, path, max_side)
            else:
                im = im.convert("L" if im.mode in ("1", "L") else "RGB")
                im = _shrink(im, max_side)
                data = torch.tensor(bytearray(im.tobytes()), dtype=torch.uint8)
                c = 1 if im.mode == "L" else 3
                img = data.reshape(im.size[1], im.size[0], c).permute(2, 0, 1).double() / 255.0
    except Image.DecompressionBombError as e:
        raise ValueError(f"{path}: {_bomb_size(path, e)} is beyond Pillow's decompression-bomb limit "
                         f"({2 * Image.MAX_IMAGE_PIXELS} pixels, twice PIL.Image.MAX_IMAGE_PIXELS"
                         f"): refused as a possible decompression bomb; the picture is "
                         f"down-sampled to --max-side ({max_side}) pixels anyway, so shrink it "
                         f"first (or, for a file you trust, raise PIL.Image.MAX_IMAGE_PIXELS "
                         f"in Python)") from None
    except (UnidentifiedImageError, OSError) as e:
        raise ValueError(f"{path}: not a readable image ({e})") from None
    if min(img.shape[-2:]) < 2:
        raise ValueError(f"{path}: the image must be at least 2x2 pixels, got "
                         f"{tuple(img.shape[-2:])}")
    return img if linear else srgb_to_linear(img)


#: Pillow modes read at full precision (:func:`_read_high_depth`): greyscale beyond 8 bits
_HIGH_DEPTH = ("I;16", "I;16L", "I;16B", "I;16N", "I", "F")


def _shrink(im, max_side):
    """``im`` area-averaged so that its longer side is at most ``max_side`` pixels."""
    from PIL import Image

    if max_side and max(im.size) > max_side:
        s = max_side / max(im.size)
        im = im.resize((max(2, round(im.size[0] * s)), max(2, round(im.size[1] * s))),
                       Image.Resampling.BOX)
    return im


def _read_high_depth(im, path: Path, max_side) -> torch.Tensor:
    """A 16-bit, 32-bit integer or float greyscale picture as ``(1, H, W)`` float64 in
    ``[0, 1]``, scaled by its type's range (:func:`read_image`); averaged in float32 (exact
    for 16-bit values), scaled in float64."""
    import numpy as np

    if im.mode == "F":
        scale = 1.0
    elif im.mode == "I":
        lo, hi = im.getextrema()
        if lo < 0 or hi > 65535:
            raise ValueError(f"{path}: a 32-bit integer picture with values in [{lo}, {hi}]: "
                             f"deeplens reads 8- and 16-bit integer and float pictures (scaled "
                             f"by 255, 65535 and 1); convert it to 16 bits or to float")
        scale = 65535.0
    else:
        scale = 65535.0
    a = np.asarray(_shrink(im.convert("F"), max_side), dtype=np.float64) / scale
    if not np.isfinite(a).all():
        raise ValueError(f"{path}: the float picture holds NaN or infinite values")
    return torch.from_numpy(np.clip(a, 0.0, 1.0).copy())[None]


def _bomb_size(path: Path, e: Exception) -> str:
    """The picture's size, ``W x H`` from its header (read by the format's own Pillow plugin,
    which does not decode the pixels), else the pixel count Pillow's error states."""
    import re

    from PIL import Image

    try:
        with open(path, "rb") as fp:
            prefix = fp.read(16)
            for fmt in Image.ID:
                factory, accept = Image.OPEN[fmt]
                if accept is None or accept(prefix):
                    fp.seek(0)
                    w, h = factory(fp, str(path)).size
                    return f"its size of {w} x {h} = {w * h} pixels"
    except Exception:  # noqa: BLE001 - only for the message
        pass
    m = re.search(r"\((\d+) pixels\)", str(e))
    return f"its size of {int(m.group(1))} pixels" if m else f"its size ({e})"


def write_image(img: torch.Tensor, path, linear: bool = False) -> Path:
    """Write ``(C, H, W)`` values in ``[0, 1]`` (linear unless ``linear``) as an 8-bit image
    (format from the suffix: .png, .jpg, .tif ...)."""
    from PIL import Image

    v = img.detach().double().clamp(0, 1)
    v = v if linear else linear_to_srgb(v)
    a = (v * 255.0 + 0.5).floor().to(torch.uint8).permute(1, 2, 0).contiguous()
    mode = "L" if a.shape[-1] == 1 else "RGB"
    im = Image.frombytes(mode, (a.shape[1], a.shape[0]),
                         bytes(a.squeeze(-1).numpy().tobytes() if mode == "L" else
                               a.numpy().tobytes()))
    path = Path(path)
    im.save(path)
    return path


def default_pixel_size(lens, resolution) -> float:
    """Pixel pitch (mm) that puts the sensor diagonal on the lens's image circle.

    Raises:
        ValueError: the lens file gives no sensor size (then pass a pitch).
    """
    if lens.sensor_semi_diameter is None:
        raise ValueError("the lens file gives no sensor size: give the pixel pitch "
                         "(--pixel-size-um)")
    H, W = resolution
    return 2.0 * lens.sensor_semi_diameter / (H * H + W * W) ** 0.5


def render_image(lens, image: torch.Tensor, depth_mm: float, *, pixel_size_mm=None,
                 spp: int = 16, seed: int = 0, options=None) -> torch.Tensor:
    """Render ``image`` ``(C, H, W)`` (linear, C = 1 or 3) placed at ``depth_mm`` in front of
    the lens onto a sensor of the same resolution (module docstring); returns ``(C, H, W)``.
    ``lens``: a Lens (traced with ``options``, ``None``: the defaults) or a
    :class:`~deeplens.optics.camera.Camera` (its lens and options; the sensor is the one made
    here for the image's resolution).

    Raises:
        ValueError: a bad depth, channel count or pixel pitch.
    """
    if image.ndim != 3 or image.shape[0] not in (1, 3):
        raise ValueError(f"render_image: image must be (C, H, W) with C = 1 or 3, got "
                         f"{tuple(image.shape)}")
    lens, _, options = unpack(lens, None, options, "render_image")
    H, W = image.shape[-2:]
    p = default_pixel_size(lens, (H, W)) if pixel_size_mm is None else float(pixel_size_mm)
    if not p > 0:
        raise ValueError(f"render_image: the pixel pitch must be > 0 mm, got {pixel_size_mm!r}")
    sensor = Sensor((H, W), p, channels=[[w] for w in RGB_WAVELENGTHS_NM])
    renderer = MonteCarloRenderer(lens, sensor, spp=spp, adjoint=False, seed=seed,
                                  options=options)
    scene = Scene(image.to(lens.dtype), float(depth_mm))
    with torch.no_grad():
        return renderer(scene)[0]
