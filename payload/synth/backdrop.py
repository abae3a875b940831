"""The distant scene behind everything: sky, clouds, far hills and textured ground.

It is rendered once into a large image on the *backdrop plane* (the image plane of a fixed
reference camera); each frame is then one ``cv2.warpPerspective`` of it (see camera.py).
``VideoBackdrop`` uses the frames of a real video instead, stretched over the same plane.
"""

import logging
import math
import os
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.errors import SourceError
from payload.synth.camera import CameraPose, Lens, MotionLimits, attitude, intrinsics, rot_x

log = logging.getLogger(__name__)

#: Height of the ego-camera above the backdrop's ground plane. Only shapes the look of the
#: ground (how fast its texture shrinks toward the horizon); the backdrop moves as if distant.
BACKDROP_ALTITUDE_M = 40.0
GROUND_TEXTURE_PX = 2048
GROUND_M_PER_PX = 1.0


def fbm(rng: np.random.Generator, shape_hw: Tuple[int, int], cell_px: float, octaves: int = 4,
        stretch_x: float = 1.0) -> np.ndarray:
    """Smooth fractal noise (float32, roughly zero mean, unit-ish range) of the given size."""
    h, w = shape_hw
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for _ in range(octaves):
        gh = max(2, int(h / cell_px) + 2)
        gw = max(2, int(w / (cell_px * stretch_x)) + 2)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.5
        cell_px /= 2.0
        if cell_px < 1.0:
            break
    return out / total


def _ground_texture(rng: np.random.Generator) -> np.ndarray:
    """A top-down patchwork of fields, forest, roads and roofs (BGR uint8, square, tileable enough)."""
    g = GROUND_TEXTURE_PX
    field_colours = np.array(
        [[60, 120, 75], [50, 100, 60], [95, 165, 185], [75, 105, 135], [85, 150, 115], [70, 135, 120],
         [110, 150, 160], [55, 85, 95]], np.float32)
    img = np.empty((g, g, 3), np.float32)
    img[:] = field_colours[rng.integers(len(field_colours))]
    for _ in range(int(rng.integers(70, 110))):
        cx, cy = rng.uniform(0, g, 2)
        w, h = rng.uniform(60, 420, 2)
        box = cv2.boxPoints(((cx, cy), (w, h), rng.uniform(0, 180))).astype(np.int32)
        colour = field_colours[rng.integers(len(field_colours))] * rng.uniform(0.85, 1.15)
        cv2.fillConvexPoly(img, box, colour.tolist())
    forest = fbm(rng, (g, g), 300.0, 3) > 0.35
    crowns = fbm(rng, (g, g), 3.0, 2)
    forest_colour = np.array([35, 65, 35], np.float32)
    img[forest] = forest_colour * (1.0 + 0.35 * crowns[forest, None])
    for _ in range(int(rng.integers(4, 9))):
        pts = np.cumsum(rng.normal(0, 120, (8, 2)), axis=0) + rng.uniform(0, g, 2)
        cv2.polylines(img, [pts.astype(np.int32)], False, (120, 125, 128), int(rng.integers(3, 7)), cv2.LINE_AA)
    for _ in range(int(rng.integers(3, 8))):
        centre = rng.uniform(0, g, 2)
        for _ in range(int(rng.integers(5, 25))):
            c = centre + rng.normal(0, 60, 2)
            roof = [(60, 70, 150), (110, 110, 115), (70, 80, 110), (150, 150, 150)][int(rng.integers(4))]
            box = cv2.boxPoints((tuple(c), tuple(rng.uniform(6, 16, 2)), rng.uniform(0, 90))).astype(np.int32)
            cv2.fillConvexPoly(img, box, roof)
    img *= 1.0 + 0.25 * fbm(rng, (g, g), 200.0, 5)[..., None]
    img *= 1.0 + 0.08 * fbm(rng, (g, g), 4.0, 2)[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


class Backdrop:
    """A rendered panorama on the backdrop plane, large enough for every allowed camera pose."""

    def __init__(self, rng: np.random.Generator, lens: Lens, limits: MotionLimits, scale: float = 0.85,
                 sky: str = "any", glare_rng: Optional[np.random.Generator] = None):
        if sky not in ("any", "clear"):
            raise ValueError("sky %r: expected any or clear" % sky)
        self.lens = lens
        self.sky = sky
        self.glare_rng = glare_rng
        self.R_ref, self.K_ref, self.size_wh = _plane_geometry(lens, limits, scale)
        # Ground plane (X, Z) metres -> backdrop pixel.
        h = BACKDROP_ALTITUDE_M
        self.ground_to_backdrop = self.K_ref @ self.R_ref.T @ np.array([[1.0, 0, 0], [0, 0, h], [0, 1.0, 0]])
        self.image = self._render(rng)

    def homography(self, pose: CameraPose) -> np.ndarray:
        """Backdrop pixel -> frame pixel for this pose."""
        return self.lens.K(pose.zoom) @ pose.rotation().T @ self.R_ref @ np.linalg.inv(self.K_ref)

    def image_for(self, index: int) -> np.ndarray:
        return self.image

    def _render(self, rng: np.random.Generator) -> np.ndarray:
        w, h = self.size_wh
        # Elevation/azimuth of every backdrop pixel, computed coarsely (they are smooth).
        step = 4
        gw, gh = w // step + 2, h // step + 2
        u, v = np.meshgrid(np.arange(gw) * step, np.arange(gh) * step)
        rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3).astype(np.float64)
        d = rays @ np.linalg.inv(self.K_ref).T @ self.R_ref.T
        elev = np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2])).reshape(gh, gw).astype(np.float32)
        az = np.arctan2(d[:, 0], d[:, 2]).reshape(gh, gw).astype(np.float32)
        big = (gw * step, gh * step)
        elev_f = cv2.resize(elev, big, interpolation=cv2.INTER_LINEAR)[:h, :w]
        az_f = cv2.resize(az, big, interpolation=cv2.INTER_LINEAR)[:h, :w]

        # Sky palette: clear blue, hazy, overcast.
        kind = int(rng.integers(3))
        if self.sky == "clear":  # drawn anyway: the other draws stay those of an "any" sky
            kind = 0
        horizon = np.array([[215, 205, 195], [200, 200, 200], [185, 185, 180]][kind], np.float32)
        zenith = np.array([[200, 145, 95], [190, 170, 150], [160, 160, 158]][kind], np.float32)
        t = np.sqrt(np.clip(elev / 0.6, 0, 1))[..., None]
        sky = horizon * (1 - t) + zenith * t
        cover = [0.25, 0.45, 0.85][kind] + rng.uniform(-0.1, 0.1)
        clouds = fbm(rng, (gh, gw), 60.0, 5, stretch_x=2.5)
        a = np.clip((clouds - (0.6 - cover)) / 0.35, 0, 1) * np.clip(elev / 0.03, 0, 1)
        shade = 235.0 - 50.0 * np.clip(fbm(rng, (gh, gw), 25.0, 3), 0, 1)
        sky = sky * (1 - a[..., None]) + shade[..., None] * a[..., None]
        sky = cv2.resize(np.clip(sky, 0, 255).astype(np.uint8), big, interpolation=cv2.INTER_LINEAR)[:h, :w]

        # Ground: a top-down texture projected onto the backdrop plane; a blurred copy far away
        # stands in for mip-mapping (the sharp one would alias into moire near the horizon).
        tex = _ground_texture(rng)
        to_tex = np.array([[1 / GROUND_M_PER_PX, 0, GROUND_TEXTURE_PX / 2], [0, -1 / GROUND_M_PER_PX, 0], [0, 0, 1]])
        H = to_tex @ np.linalg.inv(self.ground_to_backdrop)  # backdrop -> texture (inverse map)
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        near = cv2.warpPerspective(tex, H, (w, h), flags=flags, borderMode=cv2.BORDER_WRAP)
        far = cv2.warpPerspective(cv2.GaussianBlur(tex, (0, 0), 6), H, (w, h), flags=flags,
                                  borderMode=cv2.BORDER_WRAP)
        below = np.maximum(-elev_f, 1e-4)
        dist_m = BACKDROP_ALTITUDE_M / np.sin(below)
        w_far = np.clip((dist_m - 150.0) / 400.0, 0, 1).astype(np.float32)
        ground = cv2.blendLinear(near, far, 1 - w_far, w_far)
        # Near ground is magnified far beyond the texture's metre pixels: add clods, grass tufts
        # and shadows at backdrop-pixel scale so that it has trackable texture up close.
        grain = (rng.normal(0, 5, (h, w)).astype(np.float32) + 18.0 * fbm(rng, (h, w), 10.0, 3)) * (1 - w_far)
        ground = np.clip(ground.astype(np.float32) + grain[..., None], 0, 255).astype(np.uint8)
        haze_colour = horizon * 0.95
        haze = (1 - np.exp(-dist_m / rng.uniform(1200, 3000))).astype(np.float32)
        haze_img = np.empty_like(ground)
        haze_img[:] = haze_colour.astype(np.uint8)
        ground = cv2.blendLinear(ground, haze_img, 1 - haze, haze)

        # Far hills: a ragged profile just above the horizon, hazy blue-green.
        n_az = 1440
        profile = np.abs(fbm(rng, (1, n_az), 40.0, 4, stretch_x=1.0)[0]) * math.radians(1.6) + math.radians(0.1)
        hill_top = np.interp(az_f, np.linspace(-math.pi, math.pi, n_az), profile).astype(np.float32)
        hill = (elev_f >= 0) & (elev_f < hill_top)
        hill_colour = (np.array([80, 95, 80], np.float32) * 0.5 + horizon * 0.5).astype(np.uint8)

        out = sky
        out[hill] = hill_colour
        ground_mask = elev_f < 0
        out[ground_mask & ~hill] = ground[ground_mask & ~hill]
        if self.sky == "clear" and self.glare_rng is not None:
            out = _sun_glare(self.glare_rng, out, elev_f)
        log.debug("backdrop rendered size_wh=%dx%d sky=%d", w, h, kind)
        return out


def _sun_glare(rng: np.random.Generator, image: np.ndarray, elev: np.ndarray) -> np.ndarray:
    """The sun low in a clear sky: a white disc in a wide bloom that washes out everything near it
    (a light drone beside the sun has almost no contrast left)."""
    ys, xs = np.nonzero((elev > math.radians(4.0)) & (elev < math.radians(20.0)))
    if len(xs) == 0:
        return image
    k = int(rng.integers(len(xs)))
    cx, cy = float(xs[k]), float(ys[k])
    h, w = image.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = (xx - cx) ** 2 + (yy - cy) ** 2
    halo = float(rng.uniform(120.0, 400.0))
    core = float(rng.uniform(6.0, 14.0))
    gain = rng.uniform(60.0, 140.0) * np.exp(-r2 / (2 * halo ** 2)) + 255.0 * np.exp(-r2 / (2 * core ** 2))
    return np.clip(image.astype(np.float32) + gain[..., None], 0, 255).astype(np.uint8)


class VideoBackdrop:
    """The frames of a real video, stretched over the backdrop plane and played in order (looping).

    Use clips without drones (e.g. Halmstad V_BIRD_*, V_AIRPLANE_*): their objects are not labelled.
    """

    def __init__(self, path: str, lens: Lens, limits: MotionLimits, scale: float = 1.0):
        if not os.path.isfile(path):
            raise SourceError(f"synthetic background {path}: file not found (expected a video file)")
        self.path = path
        self.cap = cv2.VideoCapture(path)
        ok, first = self.cap.read()
        if not ok:
            raise SourceError(f"synthetic background {path}: cannot read frames (expected a video OpenCV can decode)")
        if "DRONE" in os.path.basename(path).upper():
            log.warning("background=%s contains a real drone that is NOT labelled; prefer V_BIRD_*/V_AIRPLANE_*", path)
        self.lens = lens
        self.R_ref, self.K_ref, size_wh = _plane_geometry(lens, limits, scale)
        bh, bw = first.shape[:2]
        # Cover the backdrop plane with the video frame (scale to cover, centred).
        s = max(size_wh[0] / bw, size_wh[1] / bh)
        ox, oy = (size_wh[0] - s * bw) / 2, (size_wh[1] - s * bh) / 2
        self.video_to_backdrop = np.array([[s, 0, ox], [0, s, oy], [0, 0, 1.0]])
        self.ground_to_backdrop = None  # no known ground plane in a real video
        self._frame: Optional[np.ndarray] = first
        self._index = 0

    def homography(self, pose: CameraPose) -> np.ndarray:
        """Video pixel -> frame pixel for this pose."""
        return self.lens.K(pose.zoom) @ pose.rotation().T @ self.R_ref @ np.linalg.inv(self.K_ref) @ self.video_to_backdrop

    def image_for(self, index: int) -> np.ndarray:
        if index != self._index:
            ok, frame = self.cap.read()
            if not ok:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, frame = self.cap.read()
            if ok:
                self._frame = frame
            self._index = index
        return self._frame

    def close(self) -> None:
        self.cap.release()


def _plane_geometry(lens: Lens, limits: MotionLimits, scale: float):
    """(R_ref, K_ref, size_wh) of a backdrop plane covering every allowed pose."""
    ref_pitch = (limits.pitch_min_rad + limits.pitch_max_rad) / 2.0
    R_ref = rot_x(ref_pitch)
    focal = lens.focal_px * scale
    K0 = intrinsics(focal, 0.0, 0.0)
    corners = np.array([[0, 0, 1], [lens.width, 0, 1], [0, lens.height, 1], [lens.width, lens.height, 1],
                        [lens.width / 2, 0, 1], [lens.width / 2, lens.height, 1]], np.float64).T
    pts = []
    for yaw in (-limits.yaw_rad, 0.0, limits.yaw_rad):
        for pitch in (limits.pitch_min_rad, limits.pitch_max_rad):
            for roll in (-limits.roll_rad, 0.0, limits.roll_rad):
                H = lens.K(limits.zoom_min) @ attitude(roll, pitch, yaw).T @ R_ref @ np.linalg.inv(K0)
                q = np.linalg.inv(H) @ corners
                pts.append((q[:2] / q[2]).T)
    pts = np.concatenate(pts)
    lo = np.floor(pts.min(axis=0)) - 8
    hi = np.ceil(pts.max(axis=0)) + 8
    return R_ref, intrinsics(focal, -lo[0], -lo[1]), (int(hi[0] - lo[0]), int(hi[1] - lo[1]))
