#!/usr/bin/env python3
"""Independent check of the rendered marker plate: detect ArUco markers with OpenCV.

Usage: detect_aruco.py IMAGE.png DICTIONARY_NAME
Prints one line per detected marker: "<id> x0 y0 x1 y1 x2 y2 x3 y3" (OpenCV corner order:
top-left, top-right, bottom-right, bottom-left of the marker; pixel centres at integers),
then a line "# opencv <version>". Exit code 2 if OpenCV cannot be imported.
Used by crates/render/tests/markers.rs; owned by the renderer.
"""
import sys

try:
    import cv2
except ImportError as e:  # the Rust test installs opencv-python-headless and retries
    print(f"cannot import cv2: {e}", file=sys.stderr)
    sys.exit(2)


def main() -> int:
    path, dict_name = sys.argv[1], sys.argv[2]
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        print(f"cannot read {path}", file=sys.stderr)
        return 1
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dict_name))
    params = cv2.aruco.DetectorParameters()
    # Sub-pixel corner refinement: the comparison with the projected truth is at ~1 px.
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(dictionary, params)
    corners, ids, _rejected = detector.detectMarkers(img)
    if ids is not None:
        for c, i in zip(corners, ids.flatten()):
            pts = " ".join(f"{v:.4f}" for v in c.reshape(-1))
            print(f"{int(i)} {pts}")
    print(f"# opencv {cv2.__version__}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
