"""Writes the camera rig presets of this folder (run: python rigs/build_presets.py).

lab18: stands in for the paper's 18-camera lab system (480 x 640): 8 cameras on a ring 35 degrees
above the cloth, 8 on a ring 5 degrees below (offset by 22.5 degrees in azimuth) and 2 looking
down from 75 degrees; all at 0.5 m from the point (0, 0, 0.06) m, fx = fy = 1000 px, principal point
at the image centre. Every camera sees the whole fall of the 10 cm cloth of the paper scenario
(checked by tests/test_core.py::test_rig_sees_whole_motion).
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from clothfit.core.observation.camera import ring_rig, save_cameras  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def lab18():
    return ring_rig(
        n_per_ring=(8, 8, 2),
        elevations_deg=(35.0, -5.0, 75.0),
        distance=0.5,
        target=(0.0, 0.0, 0.06),
        width=640,
        height=480,
        fx=1000.0,
        azimuth_offsets_deg=(0.0, 22.5, 45.0),
    )


def lab18_far():
    """lab18 with the cameras 2.5x farther away (1.25 m): the cloth spans about 80 px instead of 200,
    as in a room-sized capture system."""
    return ring_rig(
        n_per_ring=(8, 8, 2),
        elevations_deg=(35.0, -5.0, 75.0),
        distance=1.25,
        target=(0.0, 0.0, 0.06),
        width=640,
        height=480,
        fx=1000.0,
        azimuth_offsets_deg=(0.0, 22.5, 45.0),
    )


def ring8():
    return ring_rig(
        n_per_ring=(8,), elevations_deg=(25.0,), distance=0.5, target=(0.0, 0.0, 0.06), width=640, height=480, fx=1000.0
    )


if __name__ == "__main__":
    save_cameras(
        os.path.join(HERE, "lab18.json"),
        lab18(),
        {
            "description": "18 cameras: 8 at +35 deg, 8 at -5 deg, 2 at +75 deg, 0.5 m from (0, 0, 0.06), 480x640, fx 1000"
        },
    )
    save_cameras(
        os.path.join(HERE, "lab18_far.json"),
        lab18_far(),
        {"description": "lab18 at 1.25 m instead of 0.5 m: the cloth spans ~80 px"},
    )
    save_cameras(
        os.path.join(HERE, "ring8.json"),
        ring8(),
        {"description": "8 cameras on one ring at +25 deg, 0.5 m from (0, 0, 0.06), 480x640, fx 1000"},
    )
    print("wrote lab18.json, lab18_far.json, ring8.json")
