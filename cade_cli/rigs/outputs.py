"""What a rectified pair gives the user: the disparity in the rectified or the original frame
(:func:`in_frame`), metric depth and a point cloud (:func:`rectified_points`, :func:`write_ply`),
the rectified images and the epipolar picture of ``cade rectify``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cade_cli.errors import CadeError
from cade_cli.io.atomic import intended_path
from cade_cli.rigs.rectification import RigDisparity, needs_mirroring
from cade_cli.rigs.rig import Rectification, Rig


def rectified_points(disparity: np.ndarray, rectification: Rectification) -> np.ndarray:
    """(H, W, 3) float32 3-D point of each rectified reference pixel, metres, in the
    rectified reference camera's frame (``cv2.reprojectImageTo3D`` with ``Q``); NaN where
    the disparity is NaN or <= 0."""
    disparity = np.asarray(disparity, np.float32)
    usable = np.isfinite(disparity) & (disparity > 0)
    sign = -1.0 if needs_mirroring(rectification) else 1.0  # Q's disparity is x_left - x_right in the rectified frame
    points = cv2.reprojectImageTo3D((sign * np.where(usable, disparity, 1.0)).astype(np.float32), rectification.Q)
    points[~usable] = np.nan
    return points


def to_original_frame(points: np.ndarray, rectification: Rectification) -> np.ndarray:
    """(…, 3) points of the rectified reference frame in the reference camera's own frame
    (rotated by ``R1^T``)."""
    return (points.reshape(-1, 3) @ np.asarray(rectification.R1, np.float64)).reshape(points.shape).astype(np.float32)


def original_to_rectified_maps(rig: Rig, rectification: Rectification) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel of the ORIGINAL reference image, its (x, y) in the rectified frame:
    two (H, W) float32 maps, for ``cv2.remap`` of a rectified-frame image back onto the
    original reference image (``cv2.undistortPoints`` with ``R1``, ``P1``)."""
    camera = rig.camera(rectification.cameras[0])
    width, height = camera.image_size
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    pixels = np.stack([x.ravel(), y.ravel()], axis=1).reshape(-1, 1, 2)
    rectified = cv2.undistortPoints(pixels, camera.K, camera.distortion, R=rectification.R1, P=rectification.P1)
    rectified = rectified.reshape(height, width, 2)
    return rectified[..., 0].astype(np.float32), rectified[..., 1].astype(np.float32)


def to_original_image(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A rectified-frame (H', W'[, C]) float image resampled onto the original reference image
    (bilinear; NaN where the rectified frame has no pixel or a NaN neighbour)."""
    return cv2.remap(np.asarray(image, np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


def write_ply(path: Path, points: np.ndarray, colours: np.ndarray) -> int:
    """Write finite points as a binary little-endian PLY (x, y, z float32; red, green, blue uint8).

    Args:
        points: (H, W, 3) or (N, 3) float, metres; rows with a NaN are left out.
        colours: (H, W) or (N,) grey values in [0, 1], or (…, 3) RGB in [0, 1].

    Returns:
        The number of points written.
    """
    xyz = np.asarray(points, np.float32).reshape(-1, 3)
    colour = np.asarray(colours, np.float32)
    if colour.size == 3 * len(xyz) and colour.shape[-1] == 3:
        colour = colour.reshape(-1, 3)  # RGB
    else:
        colour = np.repeat(colour.reshape(-1, 1), 3, axis=1)  # grey
    keep = np.all(np.isfinite(xyz), axis=1)
    vertex = np.zeros(int(keep.sum()), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                              ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = xyz[keep, i]
    rgb = np.round(np.clip(np.nan_to_num(colour[keep]), 0, 1) * 255).astype(np.uint8)
    for i, name in enumerate(("red", "green", "blue")):
        vertex[name] = rgb[:, i]
    header = ("ply\nformat binary_little_endian 1.0\ncomment cade point cloud, metres, reference camera frame\n"
              f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertex.tobytes())
    return len(vertex)


RECTIFIED_IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
"""What :func:`write_rectified_image` writes: 8-bit PNG, or float32 TIFF (values kept)."""


def write_rectified_image(path: Path, image: np.ndarray) -> None:
    """Write a rectified (H, W) or (H, W, 3) RGB float image: a PNG as 8 bits ([0, 1] -> 0-255,
    clipped), a TIFF as float32 as it is. Writes ``path`` itself (stage it for atomicity)."""
    path = Path(path)
    values = np.asarray(image, np.float32)
    if path.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        tifffile.imwrite(path, values, photometric="rgb" if values.ndim == 3 else "minisblack")
        return
    if path.suffix.lower() != ".png":
        raise CadeError(f"cannot write {intended_path(path)}: use .png (8 bits) or .tif (float32)")
    scaled = np.round(np.clip(np.nan_to_num(values), 0, 1) * 255).astype(np.uint8)
    if scaled.ndim == 3:
        scaled = cv2.cvtColor(scaled, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), scaled):
        raise CadeError(f"could not write {intended_path(path)}; check free space and permissions")


def epipolar_picture(left: np.ndarray, right: np.ndarray, *, spacing: int = 32) -> np.ndarray:
    """(H, 2W, 3) uint8 BGR picture: the rectified pair side by side, with a horizontal line
    every ``spacing`` px across both (a scene point should sit on the same line in each)."""
    def as_bgr(image):
        scaled = np.round(np.clip(np.nan_to_num(np.asarray(image, np.float32)), 0, 1) * 255).astype(np.uint8)
        return cv2.cvtColor(scaled, cv2.COLOR_GRAY2BGR if scaled.ndim == 2 else cv2.COLOR_RGB2BGR)

    left_bgr, right_bgr = as_bgr(left), as_bgr(right)
    height = max(left_bgr.shape[0], right_bgr.shape[0])
    canvas = np.zeros((height, left_bgr.shape[1] + right_bgr.shape[1], 3), np.uint8)
    canvas[:left_bgr.shape[0], :left_bgr.shape[1]] = left_bgr
    canvas[:right_bgr.shape[0], left_bgr.shape[1]:] = right_bgr
    colours = ((0, 255, 0), (0, 160, 255), (255, 80, 255))
    for i, y in enumerate(range(spacing // 2, height, spacing)):
        cv2.line(canvas, (0, y), (canvas.shape[1] - 1, y), colours[i % len(colours)], 1, cv2.LINE_AA)
    return canvas


def luminance_of(image: np.ndarray) -> np.ndarray:
    """An (H, W) band of an (H, W) or (H, W, C) image: itself, or the Rec. 601 luminance of RGB(A)."""
    image = np.asarray(image, np.float32)
    if image.ndim == 2:
        return image
    if image.shape[2] >= 3:
        return (0.299 * image[..., 0] + 0.587 * image[..., 1] + 0.114 * image[..., 2]).astype(np.float32)
    return image[..., 0]


FRAMES = ("rectified", "original")
"""Where :func:`in_frame` puts results: the rectified reference image, or the original one."""


@dataclass(frozen=True)
class FramedDisparity:
    """A :class:`RigDisparity` in one frame (:data:`FRAMES`).

    Attributes:
        disparity: (H, W) float32 unfilled disparity, px of the RECTIFIED frame (so that
            depth = f B / d holds), NaN where invalid or outside the rectified view.
        dense: the filled map in that frame (NaN only outside the rectified view).
        valid: (H, W) bool, where ``disparity`` is finite.
        confidence: (H, W) float32 in [0, 1] (0 where invalid), or None.
        depth: (H, W) float32 depth of ``dense`` (or of ``disparity`` with ``fill=False``)
            along the frame's optical axis, metres, NaN where unknown.
        points: (N, 3) float32 3-D points of the valid rectified pixels in the reference
            camera's own frame, metres; colours: (N,) their reference band values.
    """

    disparity: np.ndarray
    dense: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray | None
    depth: np.ndarray
    points: np.ndarray
    colours: np.ndarray


def in_frame(found: RigDisparity, rig: Rig, *, frame: str = "rectified", fill: bool = True) -> FramedDisparity:
    """``found`` in the rectified reference frame, or resampled (bilinear) onto the original
    reference image (``frame="original"``: ``cv2.undistortPoints`` with R1, P1 gives each
    original pixel's place in the rectified frame). Depth and points use the dense map
    when ``fill``, else only the valid pixels."""
    if frame not in FRAMES:
        raise CadeError(f"unknown frame {frame!r}; choose rectified or original")
    rectification = found.rectification
    chosen = found.dense if fill else found.result.disparity
    rectified_xyz = rectified_points(chosen, rectification)
    camera_xyz = to_original_frame(rectified_xyz, rectification)
    keep = np.all(np.isfinite(camera_xyz), axis=2)
    points, colours = camera_xyz[keep], np.asarray(found.left, np.float32)[keep]
    if found.left.ndim == 3:
        colours = luminance_of(found.left)[keep]
    confidence = found.result.confidence
    if frame == "rectified":
        return FramedDisparity(disparity=found.result.disparity, dense=found.dense, valid=found.result.valid,
                               confidence=confidence, depth=rectified_xyz[..., 2], points=points, colours=colours)
    maps = original_to_rectified_maps(rig, rectification)
    disparity = to_original_image(found.result.disparity, maps)
    dense = to_original_image(found.dense, maps)
    depth = to_original_image(camera_xyz[..., 2], maps)
    if confidence is not None:
        confidence = np.nan_to_num(to_original_image(confidence, maps), nan=0.0)
        confidence[~np.isfinite(disparity)] = 0
    return FramedDisparity(disparity=disparity, dense=dense, valid=np.isfinite(disparity), confidence=confidence,
                           depth=depth, points=points, colours=colours)
