"""A synthetic air-to-air clip with ground truth: a camera on a moving drone watches another drone.

Every frame is the distant backdrop warped by the camera's known homography, plus cars and
birds (distractors), the target drone (sprite with motion blur), near clutter with parallax in
front of it, and sensor noise. ``Scene`` is deterministic: the same arguments give the same
pixels, and each component draws from its own random stream, so switching the target off
(``render_target=False``) leaves every other pixel unchanged.
"""

import logging
import math
from dataclasses import dataclass
from typing import Iterator, Optional, Tuple

import cv2
import numpy as np

from payload.errors import ConfigError
from payload.synth import clutter as clutter_mod
from payload.synth.backdrop import Backdrop, VideoBackdrop
from payload.synth.camera import CameraPath, Lens, MotionLimits, Wander, direction
from payload.synth.distractors import Birds, Cars
from payload.synth.drone import DroneModel

log = logging.getLogger(__name__)

#: Fraction of the frame interval the shutter is open (sets the motion-blur length).
EXPOSURE_FRACTION = 0.5
MAX_BLUR_PX = 25.0
#: ``target_in_sky``: the target's lowest elevation (the far hills reach ~2 deg).
SKY_MIN_ELEVATION_RAD = math.radians(4.0)


@dataclass(frozen=True)
class SceneFrame:
    """One rendered frame and its ground truth.

    ``target_xyxy``: tight box (x2/y2 exclusive) around the visible drone pixels, None when
    none is visible (out of view or hidden). ``homography``: backdrop pixel in the previous
    frame -> this frame (identity for index 0). ``camera_rpy_rad``: the camera's roll
    (clockwise in the image > 0), pitch (up > 0) and yaw (right > 0) in the level world frame.
    ``target_span_px``: the drone's rotor-tip-to-rotor-tip size in this frame, visible or not.
    ``target_visible``: the share of the drone's pixels (alpha-weighted) that are in the frame and
    not hidden by clutter (1.0 = fully visible, 0.0 = out of view or hidden).
    ``camera_zoom``: the lens's zoom (focal length = the scene's focal length at zoom 1 times it);
    ``camera_position_m``: the camera's position in the world frame (x right, y down, z forward);
    ``target_direction``: the unit world direction to the drone (it is far away: a direction).
    """

    image: Optional[np.ndarray]  # None from Scene.truth()
    index: int
    target_xyxy: Optional[np.ndarray]
    homography: Optional[np.ndarray]  # None from Scene.truth()
    camera_rpy_rad: Tuple[float, float, float]
    target_span_px: Optional[float] = None
    target_visible: float = 0.0
    camera_zoom: float = 1.0
    camera_position_m: Optional[Tuple[float, float, float]] = None
    target_direction: Optional[Tuple[float, float, float]] = None
    second_xyxy: Optional[np.ndarray] = None  # Scene(second_drone=True): the second drone's box, as target_xyxy


class _TargetPath:
    """The target's bearing (yaw, pitch; it is far away) and size: hovering or flying."""

    def __init__(self, rng: np.random.Generator, limits: MotionLimits, fps: float, span_px: Tuple[float, float],
                 in_sky: bool = False):
        self.rng, self.lim, self.dt_s = rng, limits, 1.0 / fps
        # In the sky: above the far hills (up to ~2 deg) with a margin, whatever the camera's roll.
        self.pitch_min_rad = max(limits.pitch_min_rad, SKY_MIN_ELEVATION_RAD) if in_sky else limits.pitch_min_rad
        self.yaw = rng.uniform(-0.5, 0.5) * limits.yaw_rad
        self.pitch = rng.uniform(self.pitch_min_rad, limits.pitch_max_rad)
        self.vel = np.zeros(2)
        self.flying = rng.random() < 0.6
        lo, hi = math.log(span_px[0]), math.log(span_px[1])
        self.span_bounds = span_px
        self.log_span_mean = rng.uniform(lo, hi)
        self.size = Wander(rng, self.log_span_mean, 0.25, 4.0, self.log_span_mean + rng.normal(0, 0.15), smooth_s=1.0)
        self.log_span = self.size.x
        self.heading = rng.uniform(-math.pi, math.pi)
        self.view_elev = rng.uniform(-0.35, 0.45)  # looking up at / down on it

    def step(self) -> None:
        r, dt = self.rng, self.dt_s
        if r.random() < dt / 4.0:  # switch between hovering and flying every ~4 s
            self.flying = not self.flying
        if self.flying:
            self.vel += r.normal(0, 0.04, 2) * math.sqrt(dt) - self.vel * dt / 5.0
            speed = np.hypot(*self.vel)
            if speed < 0.015:  # keep it actually moving
                self.vel *= 0.015 / max(speed, 1e-6)
                if speed < 1e-6:
                    self.vel = r.normal(0, 0.015, 2)
            self.vel[1] *= 0.97  # mostly horizontal flight
        else:
            self.vel = 0.9 * self.vel + r.normal(0, 0.004, 2)  # hover wobble
        self.yaw += self.vel[0] * dt
        self.pitch += self.vel[1] * dt
        lim = self.lim
        if abs(self.yaw) > lim.yaw_rad * 0.9:
            self.yaw = math.copysign(lim.yaw_rad * 0.9, self.yaw)
            self.vel[0] *= -1
        if not (self.pitch_min_rad < self.pitch < lim.pitch_max_rad + 0.05):
            self.pitch = float(np.clip(self.pitch, self.pitch_min_rad, lim.pitch_max_rad + 0.05))
            self.vel[1] *= -1
        self.log_span = self.size.step(dt)
        if self.flying and np.hypot(*self.vel) > 1e-6:
            want = math.atan2(self.vel[0], 0.3)
            self.heading += 0.05 * math.sin(want - self.heading)
        self.heading += r.normal(0, 0.01)

    def span_px(self, zoom: float, zoom_mid: float) -> float:
        lo, hi = self.span_bounds
        return float(np.clip(math.exp(self.log_span) * zoom / zoom_mid, lo, hi))


class _SecondPath:
    """A second drone (``Scene(second_drone=True)``, for tests of more than one target): its own
    airframe, size and attitude, flying at a wandering offset beside the first (a tenth to a third
    of the field of view across, a little above or below it), so the camera that follows the
    first keeps both in view most of the time."""

    def __init__(self, rng: np.random.Generator, first: _TargetPath, limits: MotionLimits, fps: float,
                 span_px: Tuple[float, float], in_sky: bool):
        self.first = first
        self.path = _TargetPath(rng, limits, fps, span_px, in_sky=in_sky)
        self.dt_s = 1.0 / fps
        self.side = 1.0 if rng.random() < 0.5 else -1.0
        hfov = limits.hfov_rad
        self.lo, self.hi = 0.1 * hfov, 0.33 * hfov
        self.dyaw = Wander(rng, 0.2 * hfov, 0.06 * hfov, 3.0, rng.uniform(self.lo, self.hi))
        self.dpitch = Wander(rng, 0.0, 0.05 * hfov, 3.0, rng.uniform(-0.08, 0.08) * hfov)

    def step(self) -> None:
        p = self.path
        p.step()  # its own motion: attitude, heading and size
        p.yaw = self.first.yaw + self.side * float(np.clip(self.dyaw.step(self.dt_s), self.lo, self.hi))
        p.pitch = max(p.pitch_min_rad, self.first.pitch + self.dpitch.step(self.dt_s))


class Scene:
    """A reproducible synthetic clip; iterate to render frames 0..frames-1 (frames=0: endless).

    Difficulty knobs: ``clutter`` near objects, ``birds``, ``cars``, ``noise`` (sensor noise
    scale, 0 = none), ``shake`` (vibration scale), ``jump_rate_hz`` (abrupt camera jumps),
    ``hfov_deg`` (field of view at zoom 1). ``background``: a video whose frames replace the
    rendered backdrop (use clips without drones, e.g. Halmstad V_BIRD_*: nothing in them is
    labelled). ``render_target=False`` renders the same clip without the drone (labels still
    describe where it would be). ``second_drone``: a second drone flies beside the first
    (``SceneFrame.second_xyxy``; not in the labels, for tests of more than one target).
    """

    def __init__(self, seed: int = 1, width: int = 1920, height: int = 1080, fps: float = 30.0,
                 frames: int = 300, target_px: Tuple[float, float] = (4.0, 80.0),
                 background: Optional[str] = None, clutter: int = 4, birds: int = 2, cars: int = 3,
                 noise: float = 1.0, shake: float = 1.0, jump_rate_hz: float = 0.1, hfov_deg: float = 60.0,
                 render_target: bool = True, drone_look: str = "any", sky: str = "any", target_in_sky: bool = False,
                 second_drone: bool = False):
        if not (0 < target_px[0] <= target_px[1]):
            raise ConfigError([f"synthetic.target_px={list(target_px)}: expected 0 < min <= max"])
        if drone_look not in ("any", "light"):
            raise ConfigError([f"synthetic.drone={drone_look!r}: expected any or light"])
        if sky not in ("any", "clear"):
            raise ConfigError([f"synthetic.sky={sky!r}: expected any or clear"])
        self.seed, self.width, self.height, self.fps, self.frames = seed, width, height, fps, frames
        self.target_px = (float(target_px[0]), float(target_px[1]))
        self.background = background
        self.n_clutter, self.n_birds, self.n_cars = clutter, birds, cars
        self.noise, self.shake, self.jump_rate_hz = noise, shake, jump_rate_hz
        self.render_target = render_target
        self.drone_look, self.sky, self.target_in_sky = drone_look, sky, target_in_sky
        self.second_drone = second_drone
        self.lens = Lens(width, height, math.radians(hfov_deg))
        if background:
            # A real frame tolerates less stretching: smaller turns, no zooming out.
            self.limits = MotionLimits(yaw_rad=math.radians(5), pitch_min_rad=math.radians(-3),
                                       pitch_max_rad=math.radians(3), roll_rad=math.radians(6),
                                       zoom_min=1.0, zoom_max=1.3, hfov_rad=math.radians(hfov_deg))
        else:
            self.limits = MotionLimits(hfov_rad=math.radians(hfov_deg))
        # Child i of a SeedSequence does not depend on how many are spawned: appending a stream
        # leaves every earlier one (and so every default scene's pixels) unchanged.
        streams = np.random.SeedSequence(seed).spawn(11)
        self._seeds = dict(zip(["backdrop", "camera", "target", "clutter", "birds", "cars", "noise", "model", "glare",
                                "second", "second_model"], streams))
        self._backdrop: Optional[Backdrop] = None

    def _rng(self, name: str) -> np.random.Generator:
        return np.random.default_rng(self._seeds[name])

    def _make_backdrop(self):
        if self.background:
            return VideoBackdrop(self.background, self.lens, self.limits)
        if self._backdrop is None:  # rendered once, shared by every iteration
            self._backdrop = Backdrop(self._rng("backdrop"), self.lens, self.limits, sky=self.sky,
                                      glare_rng=self._rng("glare"))
        return self._backdrop

    def __iter__(self) -> Iterator[SceneFrame]:
        backdrop = self._make_backdrop()
        try:
            yield from self._frames(backdrop)
        finally:
            if isinstance(backdrop, VideoBackdrop):
                backdrop.close()

    def truth(self) -> Iterator[SceneFrame]:
        """The frames' ground truth without drawing them (``image`` and ``homography`` are None):
        the same boxes as iterating the scene, at a fraction of the cost. The drone, camera and
        clutter have random streams of their own, so leaving the drawing out changes none of them."""
        return self._frames(None)

    def _frames(self, backdrop) -> Iterator[SceneFrame]:
        """Frames drawn over ``backdrop``; with None, only their ground truth (see truth())."""
        w, h, lim = self.width, self.height, self.limits
        draw = backdrop is not None
        cam = CameraPath(self._rng("camera"), lim, self.fps, shake=self.shake, jump_rate_hz=self.jump_rate_hz)
        target = _TargetPath(self._rng("target"), lim, self.fps, self.target_px, in_sky=self.target_in_sky)
        model = DroneModel(self._rng("model"), look=self.drone_look)
        second = second_model = None
        if self.second_drone:
            second = _SecondPath(self._rng("second"), target, lim, self.fps, self.target_px, self.target_in_sky)
            second_model = DroneModel(self._rng("second_model"), look=self.drone_look)
        near = clutter_mod.Clutter(self._rng("clutter"), self.lens, self.n_clutter, buildings=not self.background)
        if draw:
            birds = Birds(self._rng("birds"), lim, self.n_birds, self.fps)
            cars = Cars(self._rng("cars"), getattr(backdrop, "ground_to_backdrop", None), self.n_cars, self.fps)
            noise_rng = self._rng("noise")
            sigma = noise_rng.uniform(1.5, 4.0) * self.noise
            margin = 32
            n = noise_rng.standard_normal((h + margin, w + margin, 3), dtype=np.float32) * sigma
            noise_pos = np.clip(np.rint(n), 0, 255).astype(np.uint8)
            noise_neg = np.clip(np.rint(-n), 0, 255).astype(np.uint8)
            del n
        zoom_mid = math.sqrt(lim.zoom_min * lim.zoom_max)
        haze_colour = (205.0, 200.0, 195.0)
        H_prev = None
        dir_prev = second_prev = None
        index = 0
        while self.frames <= 0 or index < self.frames:
            target.step()
            if second is not None:
                second.step()
            pose = cam.step(target.yaw, target.pitch)
            image = step_h = None
            if draw:
                H = backdrop.homography(pose)
                image = cv2.warpPerspective(backdrop.image_for(index), H, (w, h), flags=cv2.INTER_LINEAR,
                                            borderMode=cv2.BORDER_REFLECT)
                step_h = np.eye(3) if H_prev is None else H @ np.linalg.inv(H_prev)
                step_h /= step_h[2, 2]
                H_prev = H
                cars.draw(image, H)
                birds.draw(image, self.lens, pose)

            shapes = near.shapes(pose, first=index == 0)
            box, seen, span, dir_prev = self._drone(image, target, model, pose, zoom_mid, dir_prev, shapes, haze_colour)
            second_box = None
            if second is not None:
                second_box, _, _, second_prev = self._drone(image, second.path, second_model, pose, zoom_mid,
                                                            second_prev, shapes, haze_colour)
            if draw:
                clutter_mod.draw(image, shapes)
                if sigma > 0:
                    ox, oy = noise_rng.integers(0, margin, 2)
                    cv2.add(image, noise_pos[oy:oy + h, ox:ox + w], dst=image)
                    cv2.subtract(image, noise_neg[oy:oy + h, ox:ox + w], dst=image)
            yield SceneFrame(
                image=image, index=index, target_xyxy=box, homography=step_h,
                camera_rpy_rad=(pose.roll_rad, pose.pitch_rad, pose.yaw_rad), target_span_px=span, target_visible=seen,
                camera_zoom=float(pose.zoom), camera_position_m=tuple(float(c) for c in pose.position_m),
                target_direction=tuple(float(c) for c in dir_prev), second_xyxy=second_box,
            )
            index += 1

    def _drone(self, image: Optional[np.ndarray], path: _TargetPath, model: DroneModel, pose, zoom_mid: float,
               dir_prev, shapes, haze_colour) -> Tuple[Optional[np.ndarray], float, float, np.ndarray]:
        """Draw one drone (when ``image`` is given and the target is rendered): its visible box, the
        visible share, its span in px and its direction (the next frame's ``dir_prev``)."""
        w, h = self.width, self.height
        dirs = [direction(path.yaw, path.pitch)] + ([] if dir_prev is None else [dir_prev])
        uv, depth = self.lens.project_directions(pose, np.array(dirs))
        xy = uv[0]
        span = path.span_px(pose.zoom, zoom_mid)
        # Blur by the target's own motion only: the backdrop is not blurred by camera motion,
        # so blurring the target by it would make the target stand out unnaturally.
        blur = np.zeros(2) if dir_prev is None else (xy - uv[1]) * EXPOSURE_FRACTION
        blur_len = float(np.hypot(*blur))
        if blur_len > MAX_BLUR_PX:
            blur *= MAX_BLUR_PX / blur_len
        box, seen = None, 0.0
        reach = span + MAX_BLUR_PX
        if depth[0] > 0 and -reach < xy[0] < w + reach and -reach < xy[1] < h + reach:
            tilt = (0.25 * path.vel[1] / 0.05, -0.25 * path.vel[0] / 0.05) if path.flying else (0.0, 0.0)
            tilt = (float(np.clip(tilt[0], -0.35, 0.35)), float(np.clip(tilt[1], -0.35, 0.35)))
            haze = 0.35 * (1.0 - (span - self.target_px[0]) / max(self.target_px[1] - self.target_px[0], 1e-6))
            sprite = model.render(span, (float(xy[0]), float(xy[1])), path.heading, path.view_elev, tilt,
                                  (float(blur[0]), float(blur[1])), haze=haze, haze_colour=haze_colour)
            box, seen = self._composite(image, sprite, shapes)
        return box, seen, span, dirs[0]

    def _composite(self, image: Optional[np.ndarray], sprite, shapes) -> Tuple[Optional[np.ndarray], float]:
        """Blend the sprite in (if rendering the target and given an image); return the box of its
        visible pixels and the visible share of its alpha."""
        h, w = self.height, self.width
        sh, sw = sprite.alpha.shape
        x0, y0 = max(sprite.x0, 0), max(sprite.y0, 0)
        x1, y1 = min(sprite.x0 + sw, w), min(sprite.y0 + sh, h)
        if x1 <= x0 or y1 <= y0:
            return None, 0.0
        a = sprite.alpha[y0 - sprite.y0:y1 - sprite.y0, x0 - sprite.x0:x1 - sprite.x0]
        p = sprite.colour[y0 - sprite.y0:y1 - sprite.y0, x0 - sprite.x0:x1 - sprite.x0]
        if self.render_target and image is not None:
            roi = image[y0:y1, x0:x1]
            roi[:] = np.clip(roi * (1.0 - a[..., None]) + p + 0.5, 0, 255).astype(np.uint8)
        covered = clutter_mod.mask_in(shapes, x0, y0, x1 - x0, y1 - y0) if shapes else 0
        visible = (a > 0) & (covered == 0)
        ys, xs = np.nonzero(visible)
        if len(xs) == 0:
            return None, 0.0
        seen = min(1.0, float(a[visible].sum()) / max(float(sprite.alpha.sum()), 1e-6))
        return np.array([x0 + xs.min(), y0 + ys.min(), x0 + xs.max() + 1, y0 + ys.max() + 1], np.float32), seen
