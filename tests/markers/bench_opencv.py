#!/usr/bin/env python3
"""OpenCV as the peer of `btfrig bench registration` (crates/cli/src/bench_cmd.rs).

Usage: bench_opencv.py DIR
DIR holds job.json (camera matrix K, distortion [k1, k2, p1, p2, k3], image size, marker
dictionary, plate marker corners in metres, texture size and region, repeats), green.f32
(the frame's green channel, float32 little-endian, row-major, fractions of white) and rgb.f32
(the demosaiced camera RGB, float32, h x w x 3), optionally clean.f32 (the noise-free image,
same layout). The script runs the mainstream pipeline

  cv2.aruco detection (CORNER_REFINE_SUBPIX) on the green channel scaled to 8 bits,
  cv2.undistortPoints (P = K: undistorted pixels of the same camera matrix),
  cv2.findHomography (RANSAC, 3 px) from plate points (metres) to undistorted pixels,
  cv2.remap of the RGB frame through initUndistortRectifyMap (INTER_LINEAR): the undistorted image,
  cv2.warpPerspective (INTER_LINEAR, WARP_INVERSE_MAP) of it into the texture,

timing each step (median of the repeats, time.perf_counter; the 8-bit conversion and the
undistortion maps, which a pipeline computes once per camera, are timed apart). Writes
result.json (detections, homography, times) and texture.f32 (size x size x 3 float32, row 0
at the sample's +y edge, column 0 at its -x edge, like btfrig's textures), and
texture_clean.f32 from clean.f32 through the same maps (untimed).

With "pipeline": true in job.json, the script starts from the raw frame instead (raw.u16:
uint16 little-endian photosites, h x w; "bayer" names the mosaic as btfrig does, "black" and
"white" its levels): cv2.cvtColor demosaics it (timed as demosaic_s; the Bayer code is chosen
by a self-check on a synthetic mosaic, so OpenCV's naming cannot swap red and blue), its green
channel goes to the detector, and remap + warpPerspective resample its uint16 RGB; the texture
is then converted to fractions of white above black (untimed, 256 x 256 values).

Pixel centres: OpenCV puts them at integer coordinates for remap, warpPerspective and the
ArUco corners, as btfrig does; `pixel_centre_check` pins this for the warp (a destination
pixel sampled through a 0.25 px shift of a ramp must read 0.25 more than its column).
Exit code 2 if OpenCV cannot be imported.
"""
import json
import os
import sys
import time

try:
    import cv2
    import numpy as np
except ImportError as e:  # bench_cmd.rs installs opencv-python-headless and retries
    print(f"cannot import cv2: {e}", file=sys.stderr)
    sys.exit(2)


def median_time(fn, repeat):
    times, out = [], None
    for _ in range(max(1, repeat)):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    times.sort()
    return out, times[len(times) // 2]


def pixel_centre_check():
    """Value at destination column 10 of a ramp src[y, x] = x warped with a +0.25 px shift."""
    src = np.tile(np.arange(32, dtype=np.float32), (8, 1))
    m = np.array([[1.0, 0.0, 0.25], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    dst = cv2.warpPerspective(src, m, (32, 8), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    return float(dst[4, 10])


BAYER_CODES = ["COLOR_BayerRG2RGB", "COLOR_BayerBG2RGB", "COLOR_BayerGR2RGB", "COLOR_BayerGB2RGB"]


def bayer_code(pattern):
    """The cvtColor code that turns a mosaic laid out as btfrig's `pattern` (RGGB, BGGR, GRBG,
    GBRG: the 2x2 cell from the top-left photosite) into RGB: the one that puts a mosaic lit
    only at its red sites into the red channel."""
    cell = {"RGGB": "RGGB", "BGGR": "BGGR", "GRBG": "GRBG", "GBRG": "GBRG"}[pattern]
    mosaic = np.zeros((16, 16), dtype=np.uint16)
    for dy in range(2):
        for dx in range(2):
            if cell[2 * dy + dx] == "R":
                mosaic[dy::2, dx::2] = 1000
    best, code = -1.0, None
    for name in BAYER_CODES:
        out = cv2.cvtColor(mosaic, getattr(cv2, name))[4:12, 4:12].astype(np.float64)
        score = out[:, :, 0].mean() - out[:, :, 2].mean()
        if score > best:
            best, code = score, getattr(cv2, name)
    return code


def main() -> int:
    d = sys.argv[1]
    job = json.load(open(os.path.join(d, "job.json")))
    w, h, size, repeat = job["width"], job["height"], job["size"], job["repeat"]
    k = np.array(job["K"], dtype=np.float64)
    dist = np.array(job["dist"], dtype=np.float64)
    green = np.fromfile(os.path.join(d, "green.f32"), dtype="<f4").reshape(h, w)
    rgb = np.fromfile(os.path.join(d, "rgb.f32"), dtype="<f4").reshape(h, w, 3)
    times = {}
    pipeline = bool(job.get("pipeline"))
    if pipeline:
        raw = np.fromfile(os.path.join(d, "raw.u16"), dtype="<u2").reshape(h, w)
        code = bayer_code(job["bayer"])
        rgb, times["demosaic_s"] = median_time(lambda: cv2.cvtColor(raw, code), repeat)
        black, white = float(job["black"]), float(job["white"])
        green = (rgb[:, :, 1].astype(np.float32) - black) / (white - black)

    # 8-bit grey for the detector (it needs CV_8U): the 99.9th percentile maps to 255.
    t = time.perf_counter()
    scale = float(np.percentile(green, 99.9)) or 1.0
    grey = np.clip(green * (255.0 / scale), 0, 255).astype(np.uint8)
    times["to_8bit_s"] = time.perf_counter() - t

    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, job["dictionary"]))
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(dictionary, params)
    (corners, ids, _rej), times["detect_s"] = median_time(lambda: detector.detectMarkers(grey), repeat)

    plate = {m["id"]: m["corners"] for m in job["plate"]}
    markers, src, img = [], [], []
    if ids is not None:
        for c, i in zip(corners, ids.flatten()):
            c = c.reshape(4, 2).astype(np.float64)
            markers.append({"id": int(i), "corners": c.tolist()})
            if int(i) in plate:
                src.extend(plate[int(i)])
                img.extend(c.tolist())
    result = {"opencv": cv2.__version__, "markers": markers, "H": None, "error": None,
              "pixel_centre_check": pixel_centre_check()}

    if len(src) >= 4:
        img_pts = np.array(img, dtype=np.float64).reshape(-1, 1, 2)
        und, times["undistort_points_s"] = median_time(
            lambda: cv2.undistortPoints(img_pts, k, dist, P=k), repeat)
        src_pts = np.array(src, dtype=np.float64).reshape(-1, 1, 2)
        (hmat, _mask), times["homography_s"] = median_time(
            lambda: cv2.findHomography(src_pts, und, cv2.RANSAC, 3.0), repeat)
        if hmat is None:
            result["error"] = f"findHomography failed on {len(src)} corners"
    else:
        hmat = None
        result["error"] = f"{len(markers)} markers detected, too few plate corners for a homography"

    if hmat is not None:
        result["H"] = hmat.tolist()
        (m1, m2), times["init_undistort_maps_s"] = median_time(
            lambda: cv2.initUndistortRectifyMap(k, dist, None, k, (w, h), cv2.CV_32FC1), 1)
        undistorted, times["undistort_image_s"] = median_time(
            lambda: cv2.remap(rgb, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT), repeat)
        # Texel (c, r) (integer = texel centre) -> sample-plane point -> undistorted pixel.
        x_min, x_max, y_min, y_max = job["region"]
        px, py = (x_max - x_min) / size, (y_max - y_min) / size
        a = np.array([[px, 0.0, x_min + 0.5 * px], [0.0, -py, y_max - 0.5 * py], [0.0, 0.0, 1.0]])
        m = hmat @ a
        tex, times["warp_s"] = median_time(
            lambda: cv2.warpPerspective(undistorted, m, (size, size),
                                        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                        borderMode=cv2.BORDER_CONSTANT), repeat)
        if pipeline:
            tex = (tex.astype(np.float32) - black) / (white - black)
        np.ascontiguousarray(tex, dtype="<f4").tofile(os.path.join(d, "texture.f32"))
        # The noise-free image through the same two resamplings (untimed): geometry and
        # interpolation without sensor noise.
        clean_path = os.path.join(d, "clean.f32")
        if os.path.exists(clean_path):
            clean = np.fromfile(clean_path, dtype="<f4").reshape(h, w, 3)
            clean = cv2.remap(clean, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            clean = cv2.warpPerspective(clean, m, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                        borderMode=cv2.BORDER_CONSTANT)
            np.ascontiguousarray(clean, dtype="<f4").tofile(os.path.join(d, "texture_clean.f32"))

    result["times"] = times
    result["threads"] = cv2.getNumThreads()
    json.dump(result, open(os.path.join(d, "result.json"), "w"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
