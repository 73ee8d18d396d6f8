"""Stereo pairs with exactly known disparity, rendered from layered textured planes.

Each layer is a texture defined in left-image coordinates with a disparity that is
affine in the row and, for the foreground, in the column. The right view is rendered
by mapping every right pixel back to each layer and keeping the nearest (largest
disparity) layer that covers it, so occlusions are physically right.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SyntheticPair:
    left: np.ndarray       # (H, W) float32
    right: np.ndarray      # (H, W) float32
    disparity: np.ndarray  # (H, W) float32, left view
    reliable: np.ndarray   # (H, W) bool: visible in both views, away from edges and borders
    occluded: np.ndarray   # (H, W) bool: background pixels the foreground hides in the right view


def smooth_texture(rng: np.random.Generator, shape: tuple[int, int], sigma: float = 1.5) -> np.ndarray:
    """Random texture in [0, 1] with features a few pixels wide (matchable at sub-pixel level)."""
    noise = rng.random(shape).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), sigma)
    return (blurred - blurred.min()) / (blurred.max() - blurred.min())


def _sample(texture: np.ndarray, x: np.ndarray) -> np.ndarray:
    rows = np.broadcast_to(np.arange(texture.shape[0], dtype=np.float32)[:, None], x.shape)
    return cv2.remap(texture, x.astype(np.float32), np.ascontiguousarray(rows), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def render_pair(
    rng: np.random.Generator,
    shape: tuple[int, int] = (64, 96),
    *,
    background: tuple[float, float] = (6.0, 0.0),
    foreground: tuple[float, float] | None = None,
    margin: int = 4,
    box: tuple[int, int, int, int] | None = None,
) -> SyntheticPair:
    """Render a stereo pair of a background plane and, optionally, a foreground rectangle.

    Args:
        shape: (H, W) of each view.
        background: (d0, dy): background disparity d0 + dy * y (px), constant along rows.
        foreground: (d0, dx): foreground disparity d0 + dx * x over a centred rectangle,
            nearer than the background (larger disparity); None for no foreground.
        margin: pixels this close to an occlusion, a depth edge or the left border
            (plus the largest disparity) are excluded from ``reliable``.
        box: the foreground's rows and columns (top, bottom, first, last), bottom and last
            excluded; None for the centred rectangle (the middle half of the rows and the
            middle third of the columns).
    """
    height, width = shape
    padding = 64
    bg_texture = smooth_texture(rng, (height, width + 2 * padding))
    fg_texture = smooth_texture(rng, (height, width + 2 * padding))
    rows = np.arange(height, dtype=np.float32)[:, None]
    columns = np.arange(width, dtype=np.float32)[None, :]
    bg_disparity = np.broadcast_to(background[0] + background[1] * rows, shape).astype(np.float32)

    top, bottom, first, last = box or (height // 4, 3 * height // 4, width // 3, 2 * width // 3)
    fg_mask = np.zeros(shape, bool)
    fg_disparity = np.zeros(shape, np.float32)
    if foreground is not None:
        fg_mask[top:bottom, first:last] = True
        fg_disparity = np.broadcast_to(foreground[0] + foreground[1] * columns, shape).astype(np.float32)
    disparity = np.where(fg_mask, fg_disparity, bg_disparity).astype(np.float32)

    # Textures live in left coordinates (offset by the padding); the left view samples
    # them at x, the right view at the left x that projects to each right pixel.
    left = np.where(fg_mask, _sample(fg_texture, columns + padding + 0 * rows),
                    _sample(bg_texture, columns + padding + 0 * rows))
    right_columns = columns + 0 * rows
    bg_source = right_columns + bg_disparity          # background: x = xr + d(y)
    right = _sample(bg_texture, bg_source + padding)
    covered = np.zeros(shape, bool)
    if foreground is not None:
        d0, dx = foreground
        fg_source = (right_columns + d0) / (1.0 - dx)  # x - (d0 + dx x) = xr
        covered = (fg_source >= first) & (fg_source <= last - 1) & (rows >= top) & (rows < bottom)
        right = np.where(covered, _sample(fg_texture, fg_source + padding), right)

    # A left background pixel is occluded where its right position is covered by the foreground.
    xr = np.clip(np.rint(columns - disparity).astype(int), 0, width - 1)
    occluded = ~fg_mask & covered[np.arange(height)[:, None], xr]
    edges = cv2.dilate((occluded | (cv2.Laplacian(fg_mask.astype(np.float32), -1) != 0)).astype(np.uint8),
                       np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)).astype(bool)
    reliable = ~edges & (columns >= float(np.ceil(disparity.max())) + margin) & (columns < width - margin)
    reliable &= (rows >= margin) & (rows < height - margin)
    return SyntheticPair(left.astype(np.float32), right.astype(np.float32), disparity, reliable, occluded)


def write_real_scene(folder, rng: np.random.Generator, *, shift: int = 5) -> None:
    """A real training scene in the MiddEval3 layout (``RealScenes``, ``--real-dir``): a blurred
    random texture of 120 x 200 px, im1(x - shift) = im0(x), ground truth ``shift`` everywhere."""
    from cade_cli.io.disparity import write_disparity

    folder.mkdir(parents=True)
    texture = cv2.GaussianBlur(rng.random((120, 220, 3)).astype(np.float32), (0, 0), 2.0)
    texture = np.rint(255 * (texture - texture.min()) / (texture.max() - texture.min())).astype(np.uint8)
    cv2.imwrite(str(folder / "im0.png"), texture[:, 5:205])
    cv2.imwrite(str(folder / "im1.png"), texture[:, 5 + shift:205 + shift])
    write_disparity(folder / "disp0GT.pfm", np.full((120, 200), float(shift), np.float32))
    cv2.imwrite(str(folder / "mask0nocc.png"), np.full((120, 200), 255, np.uint8))
    (folder / "calib.txt").write_text("width=200\nheight=120\nndisp=16\n")
