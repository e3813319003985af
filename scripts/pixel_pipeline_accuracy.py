"""Accuracy and speed of the pixel -> (pan, tilt) pipeline on rendered frames (a table, no asserts).

For several LED brightnesses and spot sizes: detection rate, centroid RMS error (px) against
the renderer's exact spot centres, the detector's own predicted sigma, the angular RMS error
(deg) of the exact composition and of naive "head angle + atan(pixel offset)" addition, and
median times to render a frame and to detect. 640x480, 65 deg HFOV, barrel distortion, head
quantised like an EVI-D100, views up to +-25 deg tilt.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/pixel_pipeline_accuracy.py
"""

from __future__ import annotations

import math
import time

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_detection import detect_led
from fgloc.camera.led_measurement import grab_led_pair, measurement_from_detection
from fgloc.camera.pixel_angles import pixel_to_pan_tilt, undistort_normalized
from fgloc.core.geometry import base_rotation, pan_tilt_bearing, project_pan_tilt
from fgloc.core.model import CameraPose
from fgloc.drivers.rendered_camera import LedScene, RenderSettings, SimulatedHead, SimulatedLedController

INTR = CameraIntrinsics(fx=503.0, fy=505.0, cx=321.3, cy=238.2, width=640, height=480, k1=-0.21, k2=0.05)
POSE = CameraPose(position=np.array([1.0, 0.5, 3.0]), rotation=base_rotation(2.0, 0.04, -0.03))
VIEWS = [(0.0, 0.0), (2.5, 0.436), (-1.2, -0.436), (3.1, 0.2)]


def angle(p1: float, t1: float, p2: float, t2: float) -> float:
    return math.acos(min(1.0, float(np.dot(pan_tilt_bearing(p1, t1), pan_tilt_bearing(p2, t2)))))


def run(settings: RenderSettings, per_view: int = 25, seed: int = 0) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    positions = {}
    for k, (hp, ht) in enumerate(VIEWS):
        uv = np.column_stack([rng.uniform(6, 633, per_view), rng.uniform(6, 473, per_view)])
        p, t = pixel_to_pan_tilt(INTR, uv, hp, ht)
        pts = POSE.position + (pan_tilt_bearing(p, t) * rng.uniform(3, 10, (per_view, 1))) @ POSE.rotation.T
        positions.update({f"v{k}n{i}": x for i, x in enumerate(pts)})
    scene = LedScene(positions)
    head = SimulatedHead(POSE, scene, INTR, seed=seed, angle_step=math.radians(1 / 14.4), settings=settings)
    leds = SimulatedLedController(scene)
    found = total = 0
    px_err, px_sig, ang, naive, t_render, t_detect = [], [], [], [], [], []
    for k, view in enumerate(VIEWS):
        head.move_to(*view)
        truth_px = head.visible_leds()
        for nid in [n for n in positions if n.startswith(f"v{k}")]:
            total += 1
            t0 = time.perf_counter()
            on, off = grab_led_pair(head, leds, nid)
            t1 = time.perf_counter()
            det = detect_led(on, off)
            t2 = time.perf_counter()
            t_render.append((t1 - t0) / 2)
            t_detect.append(t2 - t1)
            if not det.found:
                continue
            found += 1
            d = det.detection
            u, v = truth_px[nid]
            px_err.append((d.u - u) ** 2 + (d.v - v) ** 2)
            px_sig.append(2 * d.sigma_px**2)
            m = measurement_from_detection(det, *head.position(), INTR)
            truth = project_pan_tilt(POSE.rotation, POSE.position, positions[nid])
            ang.append(angle(m.pan, m.tilt, *truth))
            xn = undistort_normalized(INTR, [(d.u - INTR.cx) / INTR.fx, (d.v - INTR.cy) / INTR.fy])
            hp, ht = head.position()
            naive.append(angle(hp - math.atan(xn[0]), ht - math.atan(xn[1]), *truth))
    rms = lambda a: math.sqrt(float(np.mean(a))) if len(a) else float("nan")  # noqa: E731
    return {
        "found %": 100.0 * found / total,
        "centroid rms px": rms(px_err),
        "predicted px": rms(px_sig),
        "angle rms deg": math.degrees(rms(np.square(ang))),
        "naive rms deg": math.degrees(rms(np.square(naive))),
        "render ms": 1e3 * float(np.median(t_render)),
        "detect ms": 1e3 * float(np.median(t_detect)),
    }


def main() -> None:
    cases = [
        ("default (flux 1500, psf 1.2)", RenderSettings()),
        ("dim (flux 500)", RenderSettings(led_flux=500.0)),
        ("very dim (flux 200)", RenderSettings(led_flux=200.0)),
        ("wide psf 1.8", RenderSettings(led_sigma_px=1.8)),
        ("sharp psf 0.7", RenderSettings(led_sigma_px=0.7)),
        ("noisy sensor (shot 0.3)", RenderSettings(shot_gain=0.3)),
    ]
    rows = [(name, run(s)) for name, s in cases]
    keys = list(rows[0][1])
    print(f"{'case':<30}" + "".join(f"{k:>17}" for k in keys))
    for name, r in rows:
        print(f"{name:<30}" + "".join(f"{r[k]:>17.4f}" for k in keys))


if __name__ == "__main__":
    main()
