"""Write scikit-image's colour photographs into a folder: a second test set of real
photographs for ``eval.test_folder`` (they ship with scikit-image: nothing is downloaded, and
no training image is drawn from them: the training textures are procedural).

    python scripts/skimage_photos.py data/photos_skimage
    python eval.py experiment=edof eval.test_folder=data/photos_skimage
"""

from __future__ import annotations

import sys
from pathlib import Path

#: scikit-image's bundled colour photographs (``stereo_motorcycle``: its left view only; the
#: right view nearly repeats it)
PHOTOS = ("astronaut", "chelsea", "coffee", "rocket", "stereo_motorcycle")


def main(folder: str) -> list[Path]:
    import skimage.data
    import skimage.io

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in PHOTOS:
        img = getattr(skimage.data, name)()
        if isinstance(img, tuple):  # stereo_motorcycle: (left, right, disparity)
            img = img[0]
        p = out / f"{name}.png"
        skimage.io.imsave(p, img, check_contrast=False)
        paths.append(p)
    return paths


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python scripts/skimage_photos.py OUTPUT_FOLDER")
    for p in main(sys.argv[1]):
        print(p)
