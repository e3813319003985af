"""One in-process coded survey through imperfect heads: how far its readings lie from the view
model and from the centred model. Seeded; not a test (tests/test_coded_head.py asserts it).

The rig: examples/rig-simulated.json with ``--nodes`` nodes, wide 320 x 240 cameras (90 x 74
degree views), pair noise 0.03 degree, head errors cam0 = issue 17's typical sizes (tilt index
0.3 degree, collimation 0.2, trunnion -0.2, scales +-0.5 %, lever arm (4, -3) 1e-4 baseline),
cam1 ``typical`` (the same sizes, seeded signs). For every reading decoded in a view it prints
per camera the RMS (degrees, pan * cos tilt and tilt) of the reading minus

* the view model: at the view's read-back encoder angles the LED at base point q shows along
  ``M^T (q - o)`` (:func:`fgloc.drivers.imperfect_head.ideal_equivalent_directions`), read
  by its bearing; q = the node's range along its apparent (noisy ideal) bearing;
* the centred model ``head_pan_tilt(q)`` (what the head model assumed before view angles).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/coded_head_rig.py
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing  # noqa: E402
from fgloc.core.head_model import head_pan_tilt  # noqa: E402
from fgloc.drivers.imperfect_head import head_at_zoom, ideal_equivalent_directions  # noqa: E402
from fgloc.drivers.inprocess_rig import InProcessRig  # noqa: E402
from fgloc.files.rig_config import parse_rig  # noqa: E402
from fgloc.survey.session import OpenedRig, run_survey  # noqa: E402

CAM0 = {"tilt_index_deg": 0.3, "collimation_deg": 0.2, "trunnion_deg": -0.2, "pan_scale_percent": 0.5,
        "tilt_scale_percent": -0.5, "lever_y_baseline": 0.0004, "lever_z_baseline": -0.0003}


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--nodes", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    example = ROOT / "examples" / "rig-simulated.json"
    data = json.loads(example.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(a.nodes)]
    for cam in data["cameras"]:
        cam["intrinsics"] = {"fx": 160.0, "fy": 160.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
    data["sigma_deg"] = 0.03
    data["simulation"] = {"seed": a.seed, "heights": [0.1, 0.12], "occlusion": 0.05, "dead_nodes": ["n003"],
                          "head_errors": {"cam0": CAM0, "cam1": "typical"}}
    data["retry"] = {"backoff_s": 0.0}
    data["identification"] = "coded"
    rig = parse_rig(data, str(example), example.parent)
    sim = InProcessRig(rig)
    scene = sim.scene
    with tempfile.TemporaryDirectory() as tmp:
        run_survey(rig, Path(tmp) / "c", opened=OpenedRig(open_head=sim.open_head, leds=sim.leds, simulated=sim))
        records = [r for r in map(json.loads, (Path(tmp) / "c" / "journal.jsonl").read_text().splitlines())
                   if r["type"] == "view"]
    rows: dict[str, list[list[float]]] = {}
    for rec in records:
        i = scene.camera_ids.index(rec["camera"])
        pan0, tilt0 = rec["head"]
        p = head_at_zoom(scene.heads[i], scene.zoom_levers.get(i), rec["zoom"])  # type: ignore[index]
        for r in rec["readings"]:
            j = scene.node_ids.index(r["node"])
            q = np.linalg.norm(scene.nodes[j] - scene.cameras[i].position) * pan_tilt_bearing(*scene.apparent[i, j])
            vp, vt = bearing_pan_tilt(ideal_equivalent_directions(p, pan0, tilt0, q[None])[0])
            cp, ct, _, _ = head_pan_tilt(q, p, jacobians=False)
            rows.setdefault(rec["camera"], []).append([
                wrap(r["pan"] - float(vp)) * math.cos(float(vt)), r["tilt"] - float(vt),
                wrap(r["pan"] - float(cp)) * math.cos(float(ct)), r["tilt"] - float(ct)])
    out = {}
    for cid, v in sorted(rows.items()):
        e = np.degrees(np.array(v))
        out[cid] = {"readings": len(e),
                    "view_model_rms_deg": np.sqrt(np.mean(e[:, :2] ** 2, axis=0)).round(4).tolist(),
                    "view_model_max_deg": np.abs(e[:, :2]).max(axis=0).round(4).tolist(),
                    "centred_model_rms_deg": np.sqrt(np.mean(e[:, 2:] ** 2, axis=0)).round(4).tolist(),
                    "centred_model_max_deg": np.abs(e[:, 2:]).max(axis=0).round(4).tolist()}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
