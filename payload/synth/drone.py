"""The target: a small multirotor (body, four arms, motors, spinning rotor discs, skids).

A 3-D stick-and-disc model is projected orthographically (the target is distant), drawn at a
few times the final resolution and shrunk with area averaging, so that a 6 px drone is a soft
dark blob with the right proportions and an 80 px one shows arms and translucent rotors.
The result is a premultiplied colour sprite and an alpha matte, motion-blurred on request.
"""

import math
from dataclasses import dataclass
from typing import List, Tuple

import cv2
import numpy as np

#: Alpha below this is dropped: a blur tail that faint is not "drone pixels" for the label.
MIN_ALPHA = 0.05


@dataclass(frozen=True)
class Sprite:
    """A rendered target: ``x0, y0`` frame position of the top-left pixel, premultiplied
    colour (h, w, 3) float32 in 0..255 and alpha (h, w) float32 in 0..1."""

    x0: int
    y0: int
    colour: np.ndarray
    alpha: np.ndarray


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _circle(centre, radius: float, n: int = 20) -> np.ndarray:
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t),
                     np.full(n, centre[2])], 1)


#: Navigation lights (BGR): red at the front arms, green at the rear, as on most consumer drones.
NAV_RED = np.array([60.0, 60.0, 255.0])
NAV_GREEN = np.array([90.0, 255.0, 90.0])


class DroneModel:
    """One multirotor's shape and colours (drawn at random per scene). Units: span = 1.

    ``look``: "any" draws the airframe's colour (mostly dark, some grey, some white); "light"
    makes it white or light grey, half of them with navigation lights on the motors: the tiny
    light drone against a bright sky that the dark-blob cue misses (issue 16).
    """

    def __init__(self, rng: np.random.Generator, look: str = "any"):
        self.arm_r = rng.uniform(0.30, 0.36)
        self.rotor_r = 0.5 - self.arm_r
        self.body_half = rng.uniform(0.08, 0.13)
        self.body_h = rng.uniform(0.06, 0.11)
        kind = rng.random()
        if kind < 0.6:  # dark carbon / black plastic
            body = rng.uniform(25, 60)
            self.body = np.array([body, body, body * rng.uniform(0.95, 1.1)])
        elif kind < 0.85:  # grey
            body = rng.uniform(70, 110)
            self.body = np.array([body, body, body])
        else:  # white consumer drone
            body = rng.uniform(170, 215)
            self.body = np.array([body, body, body])
        self.underside = np.minimum(self.body * rng.uniform(1.0, 1.6) + 15, 230)
        self.arm = self.body * rng.uniform(0.6, 1.0) if rng.random() < 0.5 else np.array([30.0, 30, 30])
        self.motor = np.array([25.0, 25, 28])
        self.rotor = np.full(3, rng.uniform(60, 150))
        self.rotor_alpha = rng.uniform(0.25, 0.45)
        self.has_skids = rng.random() < 0.6
        self.has_gimbal = rng.random() < 0.6
        self.motors = [self.motor] * 4
        self.motor_r = 0.03
        if look == "light":  # drawn after the rest, so "any" scenes keep their random stream
            # white in sunlight: the real small white drones of Halmstad stand 77-98 grey levels
            # above their sky (docs/results.md, "Tiny light drones"); 140-235 made them isoluminant
            body = rng.uniform(225, 255)
            self.body = np.array([body, body, body * rng.uniform(0.97, 1.03)])
            self.underside = np.minimum(self.body * rng.uniform(0.85, 1.05), 245)
            self.arm = self.body * rng.uniform(0.85, 1.0)
            self.rotor = np.full(3, rng.uniform(200, 240))
            self.rotor_alpha = rng.uniform(0.45, 0.6)
            self.motor = self.body * rng.uniform(0.4, 0.8)
            if rng.random() < 0.5:  # a lit LED looks bigger than the motor it sits on
                self.motors, self.motor_r = [NAV_RED, NAV_RED, NAV_GREEN, NAV_GREEN], 0.05
        elif look != "any":
            raise ValueError("drone look %r: expected any or light" % look)

    def _parts(self) -> Tuple[List[Tuple[np.ndarray, np.ndarray]], List[np.ndarray]]:
        """Opaque convex parts as (3-D points, colour) and rotor discs as 3-D point rings."""
        b, bh = self.body_half, self.body_h
        parts = []
        box = np.array([[x, y, z] for x in (-b, b) for y in (-b * 1.3, b * 1.3) for z in (-bh / 2, bh / 2)])
        parts.append((box, self.body))
        parts.append((np.array([[-b, -b * 1.3, -bh / 2], [b, -b * 1.3, -bh / 2], [b, b * 1.3, -bh / 2],
                                [-b, b * 1.3, -bh / 2]]) * [0.9, 0.9, 1.02], self.underside))
        discs = []
        arm_w = 0.022
        for k in range(4):
            a = math.pi / 4 + k * math.pi / 2
            d = np.array([math.cos(a), math.sin(a), 0.0])
            n = np.array([-d[1], d[0], 0.0]) * arm_w
            tip = d * self.arm_r
            parts.append((np.array([n, -n, tip - n, tip + n]) + [0, 0, 0.005], self.arm))
            parts.append((np.concatenate([_circle(tip + [0, 0, -0.02], self.motor_r, 8),
                                          _circle(tip + [0, 0, 0.03], self.motor_r, 8)]), self.motors[k]))
            discs.append(_circle(tip + [0, 0, 0.035], self.rotor_r))
        if self.has_skids:
            for side in (-1, 1):
                x = side * b * 1.2
                foot = np.array([[x, -b * 1.8, -0.16], [x, b * 1.8, -0.16], [x, b * 1.8, -0.15],
                                 [x, -b * 1.8, -0.15]])
                parts.append((foot + [0, 0, 0], self.arm * 0.8 + 10))
                parts.append((np.array([[side * b * 0.6, 0, -bh / 2], [x, 0, -0.155], [x + 0.01 * side, 0, -0.155],
                                        [side * b * 0.6 + 0.01 * side, 0, -bh / 2]]), self.arm * 0.8 + 10))
        if self.has_gimbal:
            parts.append((np.concatenate([_circle([0, b * 0.9, -bh / 2 - 0.01], 0.035, 8),
                                          _circle([0, b * 0.9, -bh / 2 - 0.06], 0.03, 8)]), self.body * 0.7 + 20))
        return parts, discs

    def render(self, span_px: float, centre_xy: Tuple[float, float], heading_rad: float, view_elev_rad: float,
               tilt_rad: Tuple[float, float] = (0.0, 0.0), blur_xy: Tuple[float, float] = (0.0, 0.0),
               haze: float = 0.0, haze_colour=(200, 200, 200)) -> Sprite:
        """The drone ``span_px`` across (rotor tip to rotor tip) centred at ``centre_xy``.

        ``view_elev_rad`` > 0 looks down on it; ``tilt_rad`` (pitch, bank) is its own lean;
        ``blur_xy`` the motion during the exposure, in pixels.
        """
        ss = 8 if span_px < 16 else 4  # supersampling factor
        blur_len = math.hypot(*blur_xy)
        pad = int(math.ceil(blur_len / 2)) + 2
        half = int(math.ceil(span_px * 0.6)) + pad
        cx, cy = centre_xy
        x0, y0 = int(math.floor(cx)) - half, int(math.floor(cy)) - half
        size = 2 * half + 1
        # Body -> view: heading about the vertical, the drone's lean, then the viewing elevation.
        R = _rot("x", -view_elev_rad) @ _rot("y", tilt_rad[1]) @ _rot("x", tilt_rad[0]) @ _rot("z", heading_rad)
        scale = span_px * ss
        origin = np.array([(cx - x0) * ss, (cy - y0) * ss])

        def project(p3: np.ndarray) -> Tuple[np.ndarray, float]:
            q = p3 @ R.T  # x right, y away from the viewer, z up
            uv = np.stack([q[:, 0], -q[:, 2]], 1) * scale + origin
            return uv, float(q[:, 1].mean())

        parts, discs = self._parts()
        shaded = []
        for pts, colour in parts:
            uv, depth = project(pts)
            shaded.append((depth, uv, colour))
        shaded.sort(key=lambda item: -item[0])  # far first (painter's algorithm)
        n = size * ss
        colour_img = np.zeros((n, n, 3), np.float32)
        alpha_img = np.zeros((n, n), np.float32)
        shift = 4
        for _, uv, colour in shaded:
            hull = cv2.convexHull((uv * (1 << shift)).astype(np.int32))
            cv2.fillConvexPoly(colour_img, hull, colour.tolist(), cv2.LINE_8, shift)
            cv2.fillConvexPoly(alpha_img, hull, 1.0, cv2.LINE_8, shift)
        disc_img = np.zeros((n, n), np.float32)
        for ring in discs:
            uv, _ = project(ring)
            cv2.fillConvexPoly(disc_img, cv2.convexHull((uv * (1 << shift)).astype(np.int32)), 1.0, cv2.LINE_8, shift)
        a_d = disc_img * self.rotor_alpha
        p_d = a_d[..., None] * self.rotor.astype(np.float32)
        p_o = colour_img * alpha_img[..., None]
        if view_elev_rad >= 0:  # discs on top of the frame
            premul = p_d + p_o * (1 - a_d[..., None])
            alpha = a_d + alpha_img * (1 - a_d)
        else:  # seen from below: the frame hides the discs
            premul = p_o + p_d * (1 - alpha_img[..., None])
            alpha = alpha_img + a_d * (1 - alpha_img)
        premul = cv2.resize(premul, (size, size), interpolation=cv2.INTER_AREA)
        alpha = cv2.resize(alpha, (size, size), interpolation=cv2.INTER_AREA)
        if haze > 0:  # air between us and a far drone washes it toward the horizon colour
            premul = premul * (1 - haze) + alpha[..., None] * np.asarray(haze_colour, np.float32) * haze
        if blur_len >= 0.7:
            k = 2 * int(math.ceil(blur_len / 2)) + 1
            kernel = np.zeros((k * 4, k * 4), np.float32)
            c = k * 2
            dx, dy = blur_xy[0] * 2, blur_xy[1] * 2
            cv2.line(kernel, (int(round(c - dx)), int(round(c - dy))), (int(round(c + dx)), int(round(c + dy))),
                     1.0, 2, cv2.LINE_AA)
            kernel = cv2.resize(kernel, (k, k), interpolation=cv2.INTER_AREA)
            kernel /= kernel.sum()
            premul = cv2.filter2D(premul, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            alpha = cv2.filter2D(alpha, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        faint = alpha < MIN_ALPHA
        alpha[faint] = 0.0
        premul[faint] = 0.0
        return Sprite(x0, y0, premul, np.clip(alpha, 0.0, 1.0))
