"""Synthetic air-to-air clips with ground truth, for the demo, the tests and detector training.

A camera on a moving drone (pan, tilt, roll, zoom, vibration, abrupt jumps) looks at a
distant backdrop (sky, clouds, hills, textured ground) that moves by a KNOWN homography per
frame; near trees, poles and buildings move with parallax; birds and cars move on their own;
one multirotor target (4-80 px, motion-blurred, sometimes occluded or out of view) carries a
tight box per frame. Everything is reproducible from a seed.

    from payload.synth.scene import Scene
    for f in Scene(seed=3, width=1280, height=720, frames=300):
        f.image, f.target_xyxy, f.homography, f.camera_rpy_rad

    glad-payload synth OUT --seed 3 --frames 300      # OUT/SYN_3.mp4 + .csv + _homography.npy

Real backgrounds: ``background=`` takes a video whose frames replace the rendered backdrop
(warped by the same ego-motion). Use clips WITHOUT drones, e.g. Halmstad ``V_BIRD_*`` or
``V_AIRPLANE_*`` — their birds and aircraft are real, unlabelled distractors. A ``V_DRONE_*``
clip would add a real, unlabelled drone (a warning is logged).

Modules: camera (ego-motion, projection), backdrop (rendered or video backdrop), drone (the
target sprite), clutter (near objects, parallax), distractors (birds, cars), scene (assembly),
export (mp4 + labels).
"""


def seed_range(text: str):
    """An argparse ``type`` for scene seeds: a seed (``7``) or an inclusive range (``100-109``) as a
    list of ints; anything else an ArgumentTypeError saying what is expected."""
    import argparse

    try:
        first, _, last = text.partition("-")
        seeds = list(range(int(first), int(last or first) + 1))
    except ValueError:
        seeds = []
    if not seeds or seeds[0] < 0:
        raise argparse.ArgumentTypeError("%r: expected a seed (7) or a range of seeds (100-109)" % text)
    return seeds
