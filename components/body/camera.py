"""Overhead orthographic camera: a Pillow renderer of one arm and a ball, grayscale in [0, 1].

Pillow fills the shapes on a supersampled 8-bit canvas (about 1024 px wide, so one canvas
pixel is about 1.1 mm; a 0.1 degree pose change moves the forearm's edges by 0.6-1.3 mm);
the canvas is box-averaged down to the output resolution in exact integer arithmetic, then
blurred with a Gaussian whose width is given in metres (``blur``, default BLUR_SIGMA). Same
inputs give the same bytes. What is left of the rasterisation is edge quantisation at the
canvas pixel: finite differences of the image over 0.1 degree are within about 25-45 % of
the true derivative, over 0.4 degree much closer. The brain never differentiates the
renderer (it follows the decoder's smooth g(mu)), so this only adds a little pixel noise to
the decoder's training images.

What is drawn (background black): upper arm and forearm as capsules LIMB_WIDTH wide at
LIMB_LEVEL, the hand as a disc at HAND_LEVEL, the ball as a gray disc of radius ``ball_radius``
(default BALL_RADIUS) at BALL_LEVEL drawn on top. Limbs are wide and soft so that a rubber arm
displaced 15 cm still overlaps the arm the decoder predicts (the shoulder is shared, the
forearms overlap near the elbow): at 64 x 64 the Left and Right rubber arms have a cosine
overlap of 0.47 and 0.43 with the real arm.

The camera component draws only once for trials whose pose and ball are the same, and the
process keeps its drawings across steps and runs (:func:`kept_arm_layer`, :func:`kept_ball_alpha`):
the rubber arm is still within a trial and shared by a condition's trials, and a fit's or a
sweep's worker runs batch after batch of one protocol, whose balls are the same function of
condition and time, so after the first batch a step draws nothing.

Example::

    images = render(np.array([REST_POSE]), 64, None)      # (1, 64, 64) float32
"""
from __future__ import annotations

import functools
import math

import numpy as np
from PIL import Image, ImageDraw

from .kinematics import FOREARM, REST_POSE, SHOULDER, UPPER_ARM
from ..component import Component, ComponentError, StepFailure
from ..variables import Variable

# Field of view (m). It holds the rubber arms of every condition, the ball's path, and the
# whole decoder training range (shoulder rest +-40 deg, elbow rest +-50 deg: hands reach
# x in [-0.87, 0.06], y in [0.14, 0.69]; elbows down to y = -0.05) with a margin of two
# output pixels beyond the hand blob and three blur widths.
FIELD_X = (-0.99, 0.17)
FIELD_Y = (-0.19, 0.97)
LIMB_WIDTH = 0.08      # m, width of upper arm and forearm
HAND_RADIUS = 0.05     # m
BALL_RADIUS = 0.035    # m, default of the ball_radius parameter
BLUR_SIGMA = 0.015     # m, default of the blur parameter: soft edges (about 0.9 px at 64 x 64)
LIMB_LEVEL, HAND_LEVEL, BALL_LEVEL = 0.7, 1.0, 0.4
CANVAS_TARGET = 1024   # supersampled canvas width the renderer aims at (px)


def supersampling(resolution: int) -> int:
    """Canvas pixels per output pixel along each axis: at least 4, canvas about CANVAS_TARGET wide."""
    return max(4, math.ceil(CANVAS_TARGET / resolution))


def _check_resolution(resolution) -> int:
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise ComponentError(f"camera resolution must be an integer >= 8, got {resolution!r}")
    return int(resolution)


def _to_canvas(x, y, scale: float, origin=(0, 0)):
    """World (m) -> canvas coordinates (Pillow puts pixel centres at integers, hence the -0.5)."""
    column = (np.asarray(x) - FIELD_X[0]) / (FIELD_X[1] - FIELD_X[0]) * scale - 0.5 - origin[0]
    row = (FIELD_Y[1] - np.asarray(y)) / (FIELD_Y[1] - FIELD_Y[0]) * scale - 0.5 - origin[1]
    return column, row


def _capsule(draw, start, end, radius, fill):
    """A segment of width 2 * radius with round ends (canvas coordinates)."""
    (x0, y0), (x1, y1) = start, end
    length = math.hypot(x1 - x0, y1 - y0)
    if length > 0:
        nx, ny = -(y1 - y0) / length * radius, (x1 - x0) / length * radius
        draw.polygon([(x0 + nx, y0 + ny), (x1 + nx, y1 + ny), (x1 - nx, y1 - ny), (x0 - nx, y0 - ny)], fill=fill)
    for cx, cy in (start, end):
        draw.ellipse([cx - radius, cy - radius, cx + radius, cy + radius], fill=fill)


def _reduce(canvas: Image.Image, factor: int) -> np.ndarray:
    """Box-average a canvas by ``factor`` in exact integer arithmetic, as float32 in [0, 1]."""
    pixels = np.asarray(canvas)
    rows, columns = pixels.shape[0] // factor, pixels.shape[1] // factor
    # Rows first (contiguous memory), then columns: faster than one sum over axes (1, 3) (docs/performance.md).
    band_sums = pixels.reshape(rows, factor, -1).sum(axis=1, dtype=np.uint32)
    sums = band_sums.reshape(rows, columns, factor).sum(axis=2, dtype=np.uint32)
    return (sums / (255.0 * factor * factor)).astype(np.float32)


def _check_length(name: str, value) -> float:
    """A finite length >= 0 in metres (the blur, the ball radius), as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value < 0:
        raise ComponentError(f"camera {name} must be a finite length >= 0 m, got {value!r}")
    return float(value)


def gaussian_weights(sigma: float, truncate: float = 3.0) -> np.ndarray:
    """The 1-D Gaussian weights scipy.ndimage.gaussian_filter1d correlates with (order 0), the same numbers.

    Radius ``int(truncate * sigma + 0.5)`` taps, phi(x) = exp(-x^2 / (2 sigma^2)) normalised to sum 1, reversed
    for correlation (scipy.ndimage._filters._gaussian_kernel1d, scipy 1.x); sigma in pixels.
    """
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    return (phi / phi.sum())[::-1]


def _blur(layer: np.ndarray, resolution: int, blur: float = BLUR_SIGMA) -> np.ndarray:
    """Gaussian blur of ``blur`` metres (sd); zero outside the layer (black beyond the field of view).

    scipy's gaussian_filter(layer, sigma, mode="constant", truncate=3.0) as it computes it, rows then columns
    into an output of the layer's dtype, with the weights made once (:func:`gaussian_weights`): the same bytes
    without the wrapper's set-up on every call (the ball's small window is blurred every step).
    """
    sigma = blur / (FIELD_X[1] - FIELD_X[0]) * resolution
    if sigma <= 1e-15:  # gaussian_filter leaves such an axis alone
        return layer.astype(np.float32)
    from scipy.ndimage import correlate1d  # here, not at the top: a refused command never pays for scipy

    weights = _weights.get(sigma)
    if weights is None:
        weights = _weights[sigma] = gaussian_weights(sigma)
    output = np.zeros_like(layer)  # gaussian_filter's output: the input's dtype (float32 here), then the cast
    correlate1d(layer, weights, 0, output, "constant", 0.0, 0)
    correlate1d(output, weights, 1, output, "constant", 0.0, 0)
    return output.astype(np.float32)


_weights: dict[float, np.ndarray] = {}  # sigma (px) -> its weights; a run uses one or two


def arm_layer(pose_deg, resolution: int, blur: float = BLUR_SIGMA) -> np.ndarray:
    """The blurred image (res, res) float32 of one arm at ``pose_deg`` = (shoulder, elbow) deg; blur in m."""
    factor = supersampling(resolution)
    scale = resolution * factor
    shoulder, elbow = np.radians(pose_deg[0]), np.radians(pose_deg[0] + pose_deg[1])
    elbow_xy = (SHOULDER[0] + UPPER_ARM * math.cos(shoulder), SHOULDER[1] + UPPER_ARM * math.sin(shoulder))
    hand_xy = (elbow_xy[0] + FOREARM * math.cos(elbow), elbow_xy[1] + FOREARM * math.sin(elbow))
    points = [tuple(float(c) for c in _to_canvas(*p, scale)) for p in (SHOULDER, elbow_xy, hand_xy)]
    metre = scale / (FIELD_X[1] - FIELD_X[0])
    canvas = Image.new("L", (scale, scale), 0)
    draw = ImageDraw.Draw(canvas)
    _capsule(draw, points[0], points[1], LIMB_WIDTH / 2 * metre, round(255 * LIMB_LEVEL))
    _capsule(draw, points[1], points[2], LIMB_WIDTH / 2 * metre, round(255 * LIMB_LEVEL))
    radius = HAND_RADIUS * metre
    draw.ellipse([points[2][0] - radius, points[2][1] - radius, points[2][0] + radius, points[2][1] + radius],
                 fill=round(255 * HAND_LEVEL))
    return _blur(_reduce(canvas, factor), resolution, blur)


def _blur_radius(resolution: int, blur: float = BLUR_SIGMA) -> int:
    """Support of the blur kernel in output pixels (scipy's radius for truncate=3)."""
    return int(3.0 * blur / (FIELD_X[1] - FIELD_X[0]) * resolution + 0.5)


def ball_alpha(ball_xy, resolution: int, blur: float = BLUR_SIGMA, ball_radius: float = BALL_RADIUS):
    """The ball's blurred coverage as (rows, columns, patch), or None if no ball (NaN) or out of view.

    Only a window of output pixels around the ball (disc plus blur support) is rasterised
    and blurred; outside it the coverage is exactly zero, so this equals blurring the whole
    image, at a fraction of the cost (the ball is redrawn every step).
    """
    if not np.all(np.isfinite(ball_xy)):
        return None
    factor = supersampling(resolution)
    pixel = (FIELD_X[1] - FIELD_X[0]) / resolution
    u, v = _to_canvas(ball_xy[0], ball_xy[1], resolution)
    reach = ball_radius / pixel + 1 + _blur_radius(resolution, blur)
    c0, c1 = max(0, math.floor(u - reach)), min(resolution, math.ceil(u + reach) + 1)
    r0, r1 = max(0, math.floor(v - reach)), min(resolution, math.ceil(v + reach) + 1)
    if c0 >= c1 or r0 >= r1:
        return None
    canvas = Image.new("L", ((c1 - c0) * factor, (r1 - r0) * factor), 0)
    cx, cy = _to_canvas(ball_xy[0], ball_xy[1], resolution * factor, (c0 * factor, r0 * factor))
    radius = ball_radius / pixel * factor
    ImageDraw.Draw(canvas).ellipse([cx - radius, cy - radius, cx + radius, cy + radius], fill=255)
    return slice(r0, r1), slice(c0, c1), _blur(_reduce(canvas, factor), resolution, blur)


def composite(arm: np.ndarray, alpha, out: np.ndarray | None = None) -> np.ndarray:
    """The ball over the arm, arm * (1 - alpha) + BALL_LEVEL * alpha inside the ball's window.

    Written into ``out`` (res, res) when given, else into a new image; ``arm`` is left as it is.
    """
    image = np.empty_like(arm) if out is None else out
    image[...] = arm
    if alpha is not None:
        rows, columns, patch = alpha
        image[rows, columns] = arm[rows, columns] * (1 - patch) + np.float32(BALL_LEVEL) * patch
    return image


# Drawings the process keeps, least recently used dropped first: pure functions of their keys (the bytes of the
# pose or ball, the resolution, blur and radius), so a kept drawing is the drawing, read-only. The protocol
# draws 3 rubber-arm poses; its ball takes about 1500 steps x 3 conditions positions, each about 1 kB kept.
KEPT_ARM_LAYERS = 64
KEPT_BALLS = 16384


@functools.lru_cache(maxsize=KEPT_ARM_LAYERS)
def kept_arm_layer(pose: bytes, resolution: int, blur: float) -> np.ndarray:
    """:func:`arm_layer` of the pose whose float64 bytes are ``pose`` (shoulder, elbow deg), kept, read-only."""
    layer = arm_layer(np.frombuffer(pose, dtype=np.float64), resolution, blur)
    layer.flags.writeable = False
    return layer


@functools.lru_cache(maxsize=KEPT_BALLS)
def kept_ball_alpha(ball: bytes, resolution: int, blur: float, ball_radius: float):
    """:func:`ball_alpha` of the ball whose float64 bytes are ``ball`` (x, y m), kept; its patch read-only."""
    alpha = ball_alpha(np.frombuffer(ball, dtype=np.float64), resolution, blur, ball_radius)
    if alpha is not None:
        alpha[2].flags.writeable = False
    return alpha


def render(poses_deg, resolution: int = 64, balls=None, blur: float = BLUR_SIGMA,
           ball_radius: float = BALL_RADIUS) -> np.ndarray:
    """Images (N, res, res) float32 in [0, 1] of arms at ``poses_deg`` (N, 2) deg, with balls (N, 2) m or None.

    A ball row of NaN draws no ball. blur: sd of the Gaussian blur, m; ball_radius: m.
    Decoder training data is ``render(poses, res, None, blur=...)``.
    """
    resolution = _check_resolution(resolution)
    blur, ball_radius = _check_length("blur", blur), _check_length("ball_radius", ball_radius)
    poses = np.asarray(poses_deg, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 2 or not np.all(np.isfinite(poses)):
        raise ComponentError(f"camera poses_deg must be finite with shape (N, 2), got shape {poses.shape}")
    if balls is not None:
        balls = np.asarray(balls, dtype=np.float64)
        if balls.shape != poses.shape:
            raise ComponentError(f"camera balls must have the shape of poses_deg {poses.shape}, got {balls.shape}")
    images = np.empty((len(poses), resolution, resolution), np.float32)
    for index, pose in enumerate(poses):  # drawn afresh: the decoders' training poses seldom repeat
        alpha = None if balls is None else ball_alpha(balls[index], resolution, blur, ball_radius)
        images[index] = composite(arm_layer(pose, resolution, blur), alpha)
    return images


class Camera(Component):
    """The camera as a component: arm pose and ball in, image out (direct feedthrough).

    Trials whose pose and ball are the same bytes share one drawing (the image is a function of
    them; when every trial of the batch shares one, ``image`` is that drawing broadcast to the batch, a
    read-only view), and the arm layers and ball windows come from the drawings the process keeps
    (:func:`kept_arm_layer`, :func:`kept_ball_alpha`, keyed by the blur and radius too, so a run
    with another ``blur`` never reuses them). ``blur`` and ``ball_radius`` are one value for the
    whole batch (the trials share drawings); differing per-trial values are a ComponentError
    naming the variable.
    """

    def __init__(self, name: str = "camera", resolution: int = 64):
        self.resolution = _check_resolution(resolution)
        super().__init__(name, [
            Variable("resolution", "parameter", "Integer", start=self.resolution, unit="1", min=self.resolution,
                     max=self.resolution, description="image side, pixels (structural: fixed by the constructor)"),
            Variable("blur", "parameter", start=BLUR_SIGMA, unit="m", min=0.0,
                     description="sd of the Gaussian blur of the image (one value for every trial)"),
            Variable("ball_radius", "parameter", start=BALL_RADIUS, unit="m", min=0.0,
                     description="radius of the ball's disc (one value for every trial)"),
            Variable("arm_visible", "parameter", "Boolean", start=True, unit="1",
                     description="the arm is drawn (false: only the ball, over the black background)"),
            Variable("arm_pose", "input", "Array", shape=(2,), start=REST_POSE, unit="deg",
                     description="pose of the arm in view: shoulder (from +x), elbow (relative)"),
            Variable("ball", "input", "Array", shape=(2,), start=np.nan, unit="m",
                     description="ball position (x, y); NaN draws no ball"),
            Variable("image", "output", "Array", shape=(self.resolution, self.resolution), element="float32",
                     start=None, unit="1", min=0.0, max=1.0, depends_on=("arm_pose", "ball"),
                     description="overhead grayscale image s_v, black background"),
        ])
        self._blur_sigma, self._ball_radius = BLUR_SIGMA, BALL_RADIUS

    def check_parameters(self):
        """ComponentError naming ``blur`` or ``ball_radius`` when its value differs between the trials."""
        for name in ("blur", "ball_radius"):
            self._shared(name)

    def initialize(self):
        """Take this run's ``blur`` and ``ball_radius`` and draw the first ``image``."""
        self._blur_sigma, self._ball_radius = (self._shared(name) for name in ("blur", "ball_radius"))
        self._draw()

    def _shared(self, name: str) -> float:
        """The batch's one value of parameter ``name``; a ComponentError if the trials differ."""
        values = self.values[name]
        if np.any(values != values[0]):
            raise ComponentError(f"{self.name}.{name} = {values.tolist()} must be the same for every trial "
                                 "(the trials share one drawing of each pose)")
        return float(values[0])

    def step(self, t, h):
        """Draw ``image`` (B, res, res) float32 of the current ``arm_pose`` and ``ball``; StepFailure if a pose is
        not finite.

        Parameters
        ----------
        t, h : float
            The step's start and size, s (unused: the outputs follow the current inputs).
        """
        self._draw()

    def _draw(self):
        poses = np.asarray(self.values["arm_pose"], dtype=np.float64)
        balls = np.asarray(self.values["ball"], dtype=np.float64)
        if not np.all(np.isfinite(poses)):
            raise StepFailure(f"{self.name}.arm_pose is not finite: {poses.tolist()}")
        # Trials whose (pose, ball) are the same bytes share one drawing: the distinct rows of the raw bytes, each
        # drawn once in the order of its first trial, then gathered to every trial in one copy.
        pose_ball = np.ascontiguousarray(np.concatenate([poses, balls], axis=1))
        if (pose_ball.view(np.uint64) == pose_ball[:1].view(np.uint64)).all():  # one picture (a cohort's cell)
            firsts, which = np.zeros(1, int), np.zeros(len(pose_ball), int)
        else:
            _, firsts, which = np.unique(pose_ball.view(np.dtype((np.void, 32))).ravel(), return_index=True,
                                         return_inverse=True)
        drawn = np.empty((len(firsts), self.resolution, self.resolution), np.float32)
        for position in np.argsort(firsts, kind="stable"):
            trial = firsts[position]
            composite(kept_arm_layer(poses[trial].tobytes(), self.resolution, self._blur_sigma),
                      kept_ball_alpha(balls[trial].tobytes(), self.resolution, self._blur_sigma, self._ball_radius),
                      out=drawn[position])
        if len(drawn) == 1 and self.batch_size > 1 and self.values["arm_visible"].all():
            # one picture for the whole batch (a cell of a cohort): every trial's row is a view of it, read-only,
            # drawn once and never copied (a reader that needs its own rows makes them, as a decoder does)
            self.values["image"] = np.broadcast_to(drawn[0], (self.batch_size, *drawn.shape[1:]))
            return
        images = drawn[which.reshape(-1)]
        self._hide_arms(images, balls)
        self.values["image"] = images

    def _hide_arms(self, images: np.ndarray, balls: np.ndarray) -> None:
        """Redraw the trials whose ``arm_visible`` is false with the ball alone over the black background."""
        for trial in np.flatnonzero(~self.values["arm_visible"]):
            alpha = ball_alpha(balls[trial], self.resolution, self._blur_sigma, self._ball_radius)
            composite(np.zeros((self.resolution, self.resolution), np.float32), alpha, out=images[trial])
