"""``read_image`` beyond 8 bits and with absurd headers (issue 38 item 16): 16-bit and float
greyscale pictures at full precision, scaled by their type's range (they went through an 8-bit
conversion that clipped: a 16-bit ramp read 1.0 where it holds 0.125); a header declaring
20000 x 20000 pixels is a clear error, not a ``DecompressionBombError`` traceback."""

import struct
import zlib

import helpers as H
import numpy as np
import pytest
import torch
from PIL import Image

from deeplens.render.image import read_image

COOKE = str(H.LENS_DIR / "cooke_triplet.json")


def ramp16():
    """(4, 256) uint16: every 16-bit level k * 257 (0 .. 65535), rows equal."""
    return np.tile((np.arange(256, dtype=np.uint32) * 257).astype(np.uint16), (4, 1))


def test_a_16_bit_ramp_reads_at_full_precision(tmp_path):
    a = ramp16()
    a[:, 1] = 1   # one level below any 8-bit step: lost by an 8-bit conversion
    p = tmp_path / "r16.png"
    Image.fromarray(a).save(p)
    assert Image.open(p).mode == "I;16"
    got = read_image(p, linear=True)
    assert got.shape == (1, 4, 256) and got.dtype == torch.float64
    assert torch.equal(got[0], torch.from_numpy(a.astype(np.float64) / 65535.0))
    assert float(got[0, 0, 128]) == 128 * 257 / 65535   # 0.502; the 8-bit path read 1.0
    # sRGB decoding applies to the full-precision value
    srgb = read_image(p)
    assert float(srgb[0, 0, 1]) == pytest.approx(1 / 65535 / 12.92, rel=1e-12)


def test_a_16_bit_picture_is_area_averaged_in_full_precision(tmp_path):
    a = ramp16()
    p = tmp_path / "r16.png"
    Image.fromarray(a).save(p)
    got = read_image(p, max_side=128, linear=True)
    want = a.astype(np.float64).reshape(2, 2, 128, 2).mean(axis=(1, 3)) / 65535.0
    assert got.shape == (1, 2, 128)
    # float32 averages of 16-bit integers: exact up to float32 rounding of the mean
    assert np.abs(got[0].numpy() - want).max() <= 2 ** -24


def test_a_float_picture_reads_its_values(tmp_path):
    v = np.linspace(-0.25, 1.25, 4 * 64, dtype=np.float32).reshape(4, 64)
    p = tmp_path / "f.tif"
    Image.fromarray(v).save(p)
    assert Image.open(p).mode == "F"
    got = read_image(p, linear=True)[0].numpy()
    assert np.array_equal(got, np.clip(v.astype(np.float64), 0.0, 1.0))
    v[1, 3] = np.nan
    Image.fromarray(v).save(p)
    with pytest.raises(ValueError, match=r"f.tif: the float picture holds NaN or infinite"):
        read_image(p)


def bomb_png(path, w=20000, h=20000):
    """A PNG whose header declares ``w x h`` 8-bit grey pixels (and holds almost nothing)."""
    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0,
                                                                      0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\0")) + chunk(b"IEND", b""))
    return path


def test_a_decompression_bomb_header_is_a_clear_error(tmp_path, capsys):
    p = bomb_png(tmp_path / "huge.png")
    match = (r"huge.png: its size of 20000 x 20000 = 400000000 pixels is beyond Pillow's "
             r"decompression-bomb limit \(\d+ pixels, twice PIL.Image.MAX_IMAGE_PIXELS\)")
    with pytest.raises(ValueError, match=match):
        read_image(p, max_side=512)
    code, _, err = H.run_cli(["render", COOKE, str(p), "--depth", "1000", "-o",
                              str(tmp_path / "o.png")], capsys)
    assert code == 2 and "Traceback" not in err
    assert "20000 x 20000" in err and "--max-side (512)" in err
