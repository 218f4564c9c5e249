"""Image files into the core: every image of a folder, in name order, as mono8 arrays."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

IMAGE_SUFFIXES = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff', '.pgm', '.ppm', '.webp')


def image_files(folder: str | Path) -> list[Path]:
    """The image files of ``folder`` (by suffix, case-insensitive), sorted by name;
    ValueError when it is not a folder or holds none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f'{folder}: not a folder')
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f'{folder}: no image files ({", ".join(IMAGE_SUFFIXES)})')
    return files


def folder_images(folder: str | Path) -> Iterator[tuple[str, NDArray[np.uint8] | None]]:
    """(file name, mono8 image) of every image file of ``folder``; the image is None for a
    file OpenCV cannot read (the caller says so and goes on)."""
    import cv2
    for path in image_files(folder):
        yield path.name, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
