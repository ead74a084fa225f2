"""The images a capture starts from: a folder of photos, checked and copied as they are
(RGBA composited on white, so SIFT sees the object's outline against a plain background).

Every image is decoded once here, so an unreadable file, a size that differs from the
others or too few images stop the capture before any structure from motion runs.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from tqdm import tqdm

from ..data.dataset import composite, read_image
from ..data.llff import image_files
from ..video import to_uint8

MIN_FRAMES = 3           # fewer cannot be mapped (an initial pair plus one registration)
WHITE = np.ones(3, np.float32)


def check_count(n: int, where: Path) -> None:
    """A ValueError naming ``where`` unless there are at least MIN_FRAMES images."""
    if n < MIN_FRAMES:
        raise ValueError(f"{where}: {n} image{'s' if n != 1 else ''}, structure from motion "
                         f"needs at least {MIN_FRAMES}")


def copy_photos(src: Path, dest: Path, masks: Path | None = None) -> dict:
    """Check the photos of ``src`` and write them to ``dest`` (an existing empty folder).

    Opaque images are copied byte for byte; images with transparent pixels are composited
    on white and written as PNG under the same stem, and their alpha (8 bits) to
    ``masks/<stem>.png`` when ``masks`` (an existing folder) is given.
    Returns:
        {"source": "photos", "given": N, "size": [W, H], "transparent": bool (all images
        had transparent pixels: an object on an empty background)}.
    """
    files = image_files(src)
    check_count(len(files), src)
    size, transparent = None, []
    for file in tqdm(files, desc="frames: checking photos", unit="image", disable=None):
        img = read_image(file)              # ValueError naming the file if unreadable
        if size is None:
            size, first = img.shape[1::-1], file
        elif img.shape[1::-1] != size:
            raise ValueError(f"{file}: image is {img.shape[1]}x{img.shape[0]}, but "
                             f"{first.name} is {size[0]}x{size[1]}: a capture needs one "
                             "camera, so one image size")
        clear = img.shape[-1] == 4 and bool((img[..., 3] < 1).any())
        transparent.append(clear)
        if clear:
            rgb, _ = composite(img, WHITE)
            iio.imwrite(dest / f"{file.stem}.png", to_uint8(rgb))
            if masks is not None:
                iio.imwrite(masks / f"{file.stem}.png", to_uint8(img[..., 3]))
        else:
            shutil.copyfile(file, dest / file.name)
    names = [p.name for p in image_files(dest)]
    if len(set(names)) != len(files):
        raise ValueError(f"{src}: two images share a name once written as PNG "
                         f"({len(files)} files, {len(set(names))} names)")
    return {"source": "photos", "given": len(files), "size": list(size),
            "transparent": all(transparent)}
