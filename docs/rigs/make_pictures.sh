#!/usr/bin/env bash
# Rebuild the pictures of docs/rigs.md from the OpenCV stereo_calib sample pairs.
# Run from the repository root: bash docs/rigs/make_pictures.sh [DATA_DIR]   (default ../shared/data)
set -euo pipefail
data=${1:-../shared/data}/calibration/opencv-stereo-chessboard
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cade=.venv/bin/cade

$cade calibrate --camera "left:grey:$data/left*.jpg" --camera "right:grey:$data/right*.jpg" \
    --board chessboard:9x6 --square 0.025 -o "$work/rig.json" --vis "$work/detections"
cp "$work/detections/left_1.png" docs/rigs/detections_left01.png
cp "$work/detections/right_5.png" docs/rigs/detections_right05_outlier.png
$cade rectify "$work/rig.json" "$data/left01.jpg" "$data/right01.jpg" \
    -o "$work/left_rect.png" "$work/right_rect.png" --epipolar docs/rigs/epipolar.png
$cade disparity --rig "$work/rig.json" "$data/left01.jpg" "$data/right01.jpg" -o "$work/disparity.pfm" \
    --vis docs/rigs/disparity.png --depth "$work/depth.tif" --points "$work/cloud.ply" --max-disp 160 --fill none
.venv/bin/python - "$work/depth.tif" docs/rigs/depth.png <<'PY'
import sys
import cv2, numpy as np, tifffile
depth = tifffile.imread(sys.argv[1])  # metres, NaN unknown
near, far = 0.2, 1.2
scaled = np.clip((far - np.nan_to_num(depth, nan=far)) / (far - near), 0, 1)  # near = warm
picture = cv2.applyColorMap(np.round(scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
picture[~np.isfinite(depth)] = 0
cv2.putText(picture, f"depth {near}-{far} m (red = near), black = unknown", (10, 470), cv2.FONT_HERSHEY_SIMPLEX,
            0.6, (255, 255, 255), 1, cv2.LINE_AA)
cv2.imwrite(sys.argv[2], picture)
PY
